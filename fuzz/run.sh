#!/usr/bin/env bash
# Fuzzes pvsd's inputs with cargo-fuzz (libFuzzer) on the nightly toolchain.
#
#   fuzz/run.sh [TARGET|all] [SECONDS] [JOBS]
#
# Each target runs SECONDS (default 30) in JOBS processes (default 1),
# seeded with its committed corpus (corpus/TARGET, read only) and, for
# gltf, the real scenes' .gltf files in ../shared/scenes. What it finds
# goes to target/corpus/TARGET; a crash stops it, fails the script and
# leaves the input in artifacts/TARGET. Prints each target's executions.
set -euo pipefail
cd "$(dirname "$0")"
all=(bodies view xpvs gltf config websocket)
target=${1:-all}
secs=${2:-30}
jobs=${3:-1}
if [ "$target" = all ]; then targets=("${all[@]}"); else targets=("$target"); fi

cargo +nightly fuzz build -O
total=0
for t in "${targets[@]}"; do
  # An empty corpus folder is not in git: make it.
  mkdir -p "target/corpus/$t" "corpus/$t"
  dirs=("target/corpus/$t" "corpus/$t")
  extra=()
  if [ "$t" = gltf ]; then
    mkdir -p target/seeds/gltf
    cp ../../shared/scenes/*/*.gltf target/seeds/gltf/ 2>/dev/null || true
    dirs+=(target/seeds/gltf)
    extra=(-max_len=262144)
  fi
  log="target/$t.log"
  rm -f "$log" fuzz-*.log
  parallel=()
  if [ "$jobs" -gt 1 ]; then parallel=(-jobs="$jobs" -workers="$jobs"); fi
  status=0
  cargo +nightly fuzz run -O "$t" "${dirs[@]}" -- \
    -max_total_time="$secs" -print_final_stats=1 "${parallel[@]}" \
    "${extra[@]}" >"$log" 2>&1 || status=$?
  if [ "$jobs" -gt 1 ]; then
    # Each worker logs to fuzz-N.log; the main log repeats the last one.
    runs=$(cat fuzz-*.log | grep -o 'stat::number_of_executed_units: *[0-9]*' | awk '{s+=$2} END {print s+0}')
    cat fuzz-*.log >>"$log"
    rm -f fuzz-*.log
  else
    runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | awk '{s+=$2} END {print s+0}')
  fi
  total=$((total + runs))
  echo "$t: $runs executions in ${secs}s x $jobs"
  if [ "$status" != 0 ]; then
    grep -E 'ERROR|panicked|SUMMARY|Test unit written' "$log" | head -20 >&2
    echo "fuzz target $t failed; the input is in fuzz/artifacts/$t" >&2
    exit 1
  fi
done
echo "all: $total executions"
