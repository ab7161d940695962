#!/usr/bin/env bash
# Does a slowloris attack stop others being served? 64 loadtest users on the
# 10k city, alone and then beside 2,000 half-sent requests
# (scripts/slowloris.py); prints both frame rates and their ratio.
#
#   scripts/slowloris.sh [METHOD] [SECONDS]      (default: frustum 15)
set -euo pipefail
cd "$(dirname "$0")/.."
method=${1:-frustum}
secs=${2:-15}
cargo build --release --workspace -q
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
target/release/pvsd gen city --buildings 10000 --seed 7 -o "$work/city.glb" 2>/dev/null
target/release/pvsd serve --addr 127.0.0.1:18080 --scene "$work/city.glb" 2>"$work/serve.log" &
until curl -sf http://127.0.0.1:18080/healthz >/dev/null; do sleep 0.2; done
run() {
  target/release/loadtest --target http://127.0.0.1:18080 --scene city --users 64 \
    --duration "$secs" --method "$method" --json "$work/$1.json" 2>/dev/null | head -2
}
# Alone and attacked, twice, alternating: this VM's speed drifts by minutes.
for round in 1 2; do
  echo "== round $round: 64 users alone"
  run alone$round
  echo "== round $round: 64 users beside 2000 slowloris connections"
  python3 scripts/slowloris.py 127.0.0.1:18080 2000 --seconds $((secs + 8)) &
  loris=$!
  sleep 5
  run attacked$round
  wait $loris || true
done
python3 - "$work" <<'PY'
import json, sys
d = sys.argv[1]
load = lambda n: json.load(open(f"{d}/{n}.json"))
for r in (1, 2):
    a, b = load(f"alone{r}"), load(f"attacked{r}")
    print(f"round {r}: frames/s alone {a['rps']:.0f}, beside 2000 slowloris {b['rps']:.0f}: "
          f"{b['rps'] / a['rps']:.0%} kept; errors {a['errors']} / {b['errors']}; "
          f"p99 {a['p99_ms']:.2f} / {b['p99_ms']:.2f} ms")
alone = sum(load(f"alone{r}")["rps"] for r in (1, 2))
attacked = sum(load(f"attacked{r}")["rps"] for r in (1, 2))
print(f"both rounds: {attacked / alone:.0%} of the unloaded frames/s kept")
PY
