#!/usr/bin/env bash
# Starts REPLICAS `talkin serve` replicas of RUN on 127.0.0.1:8081.. and HAProxy in front
# of them on 127.0.0.1:8080 (deploy/haproxy.cfg; stats on 127.0.0.1:8404), in the
# foreground; Ctrl-C stops them all, each replica draining first. A replica that exits
# (SIGTERM for a rolling restart, a crash) is started again.
#
#   deploy/start.sh RUN                   # 2 replicas
#   REPLICAS=3 deploy/start.sh RUN -- --workers 1 --size 270x270
#   deploy/start.sh restart               # rolling restart of the running replicas
#
# Environment: REPLICAS (1-3, default 2), TALKIN (the binary; default `talkin` on PATH),
# HAPROXY (default `haproxy`), TALKIN_DEPLOY_DIR (pid files and logs, default
# /tmp/talkin-deploy), TALKIN_FRAME_TIMEOUT (see haproxy.cfg). Arguments after `--` go
# to every `talkin serve`.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
dir="${TALKIN_DEPLOY_DIR:-/tmp/talkin-deploy}"
talkin="${TALKIN:-talkin}"
haproxy="${HAPROXY:-haproxy}"
replicas="${REPLICAS:-2}"

health() { curl -fsS -o /dev/null "http://127.0.0.1:$1/health" 2>/dev/null; }

if [ "${1:-}" = restart ]; then
  # One replica at a time: SIGTERM (it drains, finishes its requests and exits; its
  # supervisor loop starts it again), then wait until it is ready before the next.
  for pidfile in "$dir"/r*.pid; do
    r="$(basename "$pidfile" .pid)"
    port=$((8080 + ${r#r}))
    echo "restarting $r (pid $(cat "$pidfile"))"
    kill -TERM "$(cat "$pidfile")"
    while health "$port"; do sleep 0.2; done
    until health "$port"; do sleep 0.5; done
    sleep 3 # two health checks: HAProxy has it back in rotation
  done
  exit 0
fi

run="${1:?usage: deploy/start.sh RUN [-- serve options] | deploy/start.sh restart}"
shift
[ "${1:-}" = -- ] && shift
case "$replicas" in 1 | 2 | 3) ;; *) echo "REPLICAS: expected 1, 2 or 3, found $replicas" >&2; exit 1 ;; esac
mkdir -p "$dir"
stopping=0
supervisors=()

# Runs replica $1 until the script stops, starting it again whenever it exits.
supervise() {
  local i="$1"
  shift
  trap 'stopping=1; [ -n "${pid:-}" ] && kill -TERM "$pid" 2>/dev/null; wait "${pid:-}" 2>/dev/null; exit 0' TERM INT
  while [ "$stopping" = 0 ]; do
    # --drain-delay 3: HAProxy checks every second and needs two failed checks.
    "$talkin" serve --run "$run" --addr "127.0.0.1:$((8080 + i))" --drain-delay 3 "$@" \
      >>"$dir/r$i.log" 2>&1 &
    pid=$!
    echo "$pid" >"$dir/r$i.pid"
    wait "$pid" || true
    [ "$stopping" = 0 ] && sleep 0.5
  done
}

for i in $(seq 1 "$replicas"); do
  supervise "$i" "$@" &
  supervisors+=("$!")
done
"$haproxy" -db -f "$here/haproxy.cfg" &
lb=$!
trap 'kill -TERM "${supervisors[@]}" 2>/dev/null; wait "${supervisors[@]}"; kill -TERM "$lb"; wait "$lb"' INT TERM
echo "balancer http://127.0.0.1:8080 (stats http://127.0.0.1:8404), $replicas replicas, logs in $dir"
wait "$lb"
