#!/usr/bin/env bash
# The soak: pvsd serving the 10k city to 64 walking users at 70% of the
# frame rate it reaches closed-loop, sessions churning (each user leaves
# and joins again every 200 frames), for MINUTES (default 30); the server's
# resident memory and open files sampled every 10 s. Writes
# docs/soak.csv, docs/soak.svg (the plot) and prints the summary. Not in
# CI (a one-minute form is: loadtest/tests, "a minute of churning sessions").
#
#   scripts/soak.sh [MINUTES] [METHOD]        (default: 30 auto)
set -euo pipefail
cd "$(dirname "$0")/.."
minutes=${1:-30}
method=${2:-auto}
users=64
cargo build --release --workspace -q
work=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$work"' EXIT
target/release/pvsd gen city --buildings 10000 --seed 7 -o "$work/city.glb" 2>/dev/null
target/release/pvsd serve --addr 127.0.0.1:18081 --scene "$work/city.glb" \
  --bake-dir "$work/bakes" 2>"$work/serve.log" &
pid=$!
until curl -sf http://127.0.0.1:18081/healthz >/dev/null; do sleep 0.2; done
# Let the background ranking finish, so `auto` has chosen.
until curl -s http://127.0.0.1:18081/scenes | grep -q '"status":"measured"'; do sleep 1; done
echo "== capacity: $users users, closed loop, churn 200, 15 s, $method"
target/release/loadtest --target http://127.0.0.1:18081 --scene city --users $users \
  --duration 15 --churn 200 --method "$method" --json "$work/capacity.json" 2>/dev/null | head -2
rate=$(python3 -c "import json; r=json.load(open('$work/capacity.json')); print(round(0.7 * r['rps'] / $users, 2))")
echo "== soak: $users users at $rate frames/s each (70%), churn 200, $minutes min"
out=docs/soak.csv
echo "seconds,rss_kib,fds" >"$out"
start=$(date +%s)
target/release/loadtest --target http://127.0.0.1:18081 --scene city --users $users \
  --duration $((minutes * 60)) --rate "$rate" --churn 200 --method "$method" \
  --json "$work/soak.json" 2>"$work/soak.log" >"$work/soak.txt" &
load=$!
while kill -0 $load 2>/dev/null; do
  rss=$(awk '/^VmRSS:/ {print $2}' /proc/$pid/status)
  fds=$(ls /proc/$pid/fd | wc -l)
  echo "$(( $(date +%s) - start )),$rss,$fds" >>"$out"
  sleep 10
done
wait $load
cat "$work/soak.txt"
cp "$work/soak.log" /tmp/soak-progress.log
cp "$work/soak.json" docs/soak.json
python3 scripts/soak_plot.py docs/soak.csv docs/soak.json docs/soak.svg
