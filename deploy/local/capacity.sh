#!/usr/bin/env bash
# Frames a second per server core, per method, on one scene: the figure
# the README's capacity table ("Running many replicas") is computed from.
#
#   deploy/local/capacity.sh SCENE.glb [METHOD...]
#
# Starts `pvsd serve` on the scene, runs `loadtest` closed-loop against it
# for each method (64 users, sessions, street walks, DURATION s each), and
# divides the frames answered by the CPU seconds the server process used
# in that time (/proc/PID/stat: user + system), so the load generator's
# share of the machine does not count against the server. Prints one line
# a method: frames/s, p99, server CPU seconds, frames per CPU second.
# Environment: PVSD, LOADTEST (binaries; default on PATH), USERS (64),
# DURATION (10).
set -euo pipefail

scene=${1:?usage: capacity.sh SCENE.glb [METHOD...]}
shift
methods=("$@")
[ ${#methods[@]} -gt 0 ] || methods=(frustum horizon occlusion_tree supporting_planes auto)
PVSD=${PVSD:-pvsd}
LOADTEST=${LOADTEST:-loadtest}
USERS=${USERS:-64}
DURATION=${DURATION:-10}
id=$(basename "${scene%.*}")
work=$(mktemp -d)
trap 'kill "$server" 2>/dev/null || true; rm -rf "$work"' EXIT

"$PVSD" serve --scene "$scene" --addr 127.0.0.1:0 > "$work/serve.log" 2>&1 &
server=$!
until grep -q "ready: every scene is loaded" "$work/serve.log"; do
  kill -0 "$server" 2>/dev/null || { cat "$work/serve.log" >&2; exit 1; }
  sleep 0.2
done
port=$(sed -n 's/.*listening on http:\/\/127\.0\.0\.1:\([0-9]*\).*/\1/p' "$work/serve.log" | head -1)
ticks=$(getconf CLK_TCK)
cpu_s() { awk -v t="$ticks" '{ print ($14 + $15) / t }' "/proc/$server/stat"; }

printf '%-20s %10s %8s %8s %14s %7s\n' method "frames/s" "p99 ms" "cpu s" "frames/cpu-s" errors
for method in "${methods[@]}"; do
  before=$(cpu_s)
  "$LOADTEST" --target "http://127.0.0.1:$port" --scene "$id" --method "$method" \
    --users "$USERS" --duration "$DURATION" --json "$work/r.json" > /dev/null 2>&1
  after=$(cpu_s)
  python3 - "$work/r.json" "$method" "$before" "$after" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
cpu = float(sys.argv[4]) - float(sys.argv[3])
answered = r["requests"] - r["errors"] - r["lost"]
print(f'{sys.argv[2]:<20} {r["rps"]:>10.0f} {r["p99_ms"]:>8.2f} {cpu:>8.2f} {answered / cpu:>14.0f} {r["errors"]:>7}')
EOF
done
