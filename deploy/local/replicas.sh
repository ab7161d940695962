#!/usr/bin/env bash
# Several pvsd replicas behind a real nginx on this machine, under load,
# with one replica killed and one added mid-run (issue 20's test;
# loadtest/tests/replicas.rs runs it and checks what it wrote).
#
#   deploy/local/replicas.sh OUT_DIR
#
# Three replicas (r1..r3) serve a generated city on loopback ports; nginx
# hashes requests on their routing keys (deploy/nginx/). `loadtest` walks
# through nginx with sessions, WebSockets and walkthroughs. A third of the
# way in, the replica to kill is picked (one that holds sessions, and not
# every walkthrough, so some walkthroughs survive it) and killed with
# SIGKILL; two thirds in, r4 starts, nginx is reloaded with the ring as a
# cluster's DNS would give it (the dead replica gone, r4 in). The marks
# file splits loadtest's report into those phases.
#
# Writes to OUT_DIR: report.json (loadtest --json), marks, killed (the
# killed replica's name), r*.log, nginx/. Environment: PVSD and LOADTEST
# (the binaries; default: on PATH), NGINX_BIN (default: nginx on PATH or
# /usr/sbin/nginx), USERS (24), RATE (frames/s per user, 20), DURATION
# (whole seconds, 30), BUILDINGS (300).
set -euo pipefail

out=${1:?usage: replicas.sh OUT_DIR}
here=$(cd "$(dirname "$0")" && pwd)
nginx_dir=$here/../nginx
PVSD=${PVSD:-pvsd}
LOADTEST=${LOADTEST:-loadtest}
NGINX_BIN=${NGINX_BIN:-$(command -v nginx || echo /usr/sbin/nginx)}
USERS=${USERS:-24}
RATE=${RATE:-20}
DURATION=${DURATION:-30}
BUILDINGS=${BUILDINGS:-300}

mkdir -p "$out/nginx/logs"
out=$(cd "$out" && pwd)
: > "$out/marks"
declare -A pid port

load=""
cleanup() {
  [ -z "$load" ] || kill "$load" 2>/dev/null || true
  for name in "${!pid[@]}"; do kill -9 "${pid[$name]}" 2>/dev/null || true; done
  if [ -f "$out/nginx/nginx.pid" ]; then
    kill "$(cat "$out/nginx/nginx.pid")" 2>/dev/null || true
  fi
}
trap cleanup EXIT

now_ms() { date +%s%3N; }
mark() { echo "$(now_ms) $1" >> "$out/marks"; echo "== $(date +%T) $1"; }

# A free loopback port (the kernel's pick; nothing holds it after).
free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'
}

# Starts replica $1 and waits until it says it is ready.
start_replica() {
  local name=$1
  "$PVSD" serve --scene "$out/city.glb" --bake-dir "$out/bakes" --replica "$name" \
    --addr 127.0.0.1:0 > "$out/$name.log" 2>&1 &
  pid[$name]=$!
  local deadline=$((SECONDS + 60))
  until grep -q "ready: every scene is loaded" "$out/$name.log"; do
    if ! kill -0 "${pid[$name]}" 2>/dev/null || [ $SECONDS -gt $deadline ]; then
      echo "replica $name did not become ready:" >&2
      cat "$out/$name.log" >&2
      exit 1
    fi
    sleep 0.1
  done
  port[$name]=$(sed -n 's/.*listening on http:\/\/127\.0\.0\.1:\([0-9]*\).*/\1/p' "$out/$name.log" | head -1)
  curl -sf "http://127.0.0.1:${port[$name]}/healthz/ready" > /dev/null
  echo "replica $name ready on port ${port[$name]} (pid ${pid[$name]})"
}

# nginx.conf with the ring of replicas $@ (the upstream is the only part
# that is not deploy/nginx's: a cluster resolves it from DNS instead).
write_nginx_conf() {
  {
    echo "worker_processes 1;"
    echo "pid $out/nginx/nginx.pid;"
    echo "error_log $out/nginx/logs/error.log warn;"
    echo "events { worker_connections 4096; }"
    echo "http {"
    echo "  access_log off;"
    echo "  client_body_temp_path $out/nginx/client_body;"
    echo "  proxy_temp_path $out/nginx/proxy;"
    echo "  fastcgi_temp_path $out/nginx/fastcgi;"
    echo "  uwsgi_temp_path $out/nginx/uwsgi;"
    echo "  scgi_temp_path $out/nginx/scgi;"
    echo "  include $nginx_dir/pvsd-http.conf;"
    echo "  upstream pvsd {"
    echo "    hash \$pvsd_key consistent;"
    for name in "$@"; do
      echo "    server 127.0.0.1:${port[$name]} max_fails=1 fail_timeout=5s;"
    done
    echo "    keepalive 64;"
    echo "  }"
    echo "  server {"
    echo "    listen 127.0.0.1:$nginx_port;"
    echo "    include $nginx_dir/pvsd-locations.conf;"
    echo "  }"
    echo "}"
  } > "$out/nginx/nginx.conf"
  "$NGINX_BIN" -t -q -e "$out/nginx/logs/error.log" -p "$out/nginx" -c "$out/nginx/nginx.conf"
}

# What a replica's /metrics says of one gauge (0 when it has none yet).
gauge() {
  local v
  v=$(curl -sf "http://127.0.0.1:${port[$1]}/metrics" | awk -v m="$2" '$1 == m { print $2 }') || {
    echo "replica $1 did not answer /metrics" >&2
    exit 1
  }
  echo "${v:-0}"
}

"$PVSD" gen city --buildings "$BUILDINGS" --seed 7 -o "$out/city.glb" 2> /dev/null
# The first replica bakes; the others read its bakes.
for name in r1 r2 r3; do start_replica "$name"; done

nginx_port=$(free_port)
write_nginx_conf r1 r2 r3
# (Its output to its log: daemonized, it would hold the caller's pipes.)
"$NGINX_BIN" -e "$out/nginx/logs/error.log" -p "$out/nginx" -c "$out/nginx/nginx.conf" \
  >> "$out/nginx/logs/error.log" 2>&1
echo "nginx on port $nginx_port"

# Users on HTTP sessions (session and walkthrough modes) leave and join
# every 37 frames (1.85 s): sessions made
# after the kill and after the new replica joined, on a period that does
# not line up with the kill.
"$LOADTEST" --target "http://127.0.0.1:$nginx_port" --scene city \
  --mode session,ws,walkthrough --group 2 --users "$USERS" --rate "$RATE" \
  --duration "$DURATION" --churn 37 --marks "$out/marks" --json "$out/report.json" \
  > "$out/loadtest.txt" 2> "$out/loadtest.log" &
load=$!

sleep $((DURATION / 3))
# The replica to kill: most sessions among those that do not hold every
# walkthrough (so walkthroughs on the survivors go on), preferring one
# that holds a walkthrough (so its users must rejoin).
total=0
for name in r1 r2 r3; do total=$((total + $(gauge "$name" pvsd_walkthroughs))); done
victim="" best=-1
for name in r1 r2 r3; do
  s=$(gauge "$name" pvsd_sessions) w=$(gauge "$name" pvsd_walkthroughs)
  echo "replica $name: $s sessions, $w walkthroughs"
  [ "$s" -gt 0 ] && [ "$w" -lt "$total" ] || continue
  score=$((s + (w > 0 ? 1000 : 0)))
  if [ "$score" -gt "$best" ]; then best=$score victim=$name; fi
done
[ -n "$victim" ] || { echo "no replica fits to be killed" >&2; exit 1; }
echo "$victim" > "$out/killed"
mark "kill-$victim"
kill -9 "${pid[$victim]}"
wait "${pid[$victim]}" 2>/dev/null || true
unset "pid[$victim]"

sleep $((DURATION / 3))
start_replica r4
survivors=()
for name in r1 r2 r3 r4; do [ "$name" = "$victim" ] || survivors+=("$name"); done
write_nginx_conf "${survivors[@]}"
mark "add-r4"
"$NGINX_BIN" -e "$out/nginx/logs/error.log" -p "$out/nginx" -c "$out/nginx/nginx.conf" -s reload \
  >> "$out/nginx/logs/error.log" 2>&1

wait "$load"
cat "$out/loadtest.txt"
for name in "${survivors[@]}"; do
  echo "replica $name: $(gauge "$name" pvsd_sessions) sessions, $(gauge "$name" pvsd_walkthroughs) walkthroughs at the end"
done
