#!/bin/sh
# The image's entry point: one role per container (docker/README.md, docs/deploy.md).
#
#   head            the Ray head (GCS); RAY_HEAD_CPUS logical CPUs (default 0: no tracer here)
#   worker          a Ray worker node joining RAY_ADDRESS; RAY_WORKER_CPUS (default: all)
#   api             a 0-CPU Ray node for the service's driver, then `tilerender serve` on
#                   0.0.0.0:API_PORT (8000) joining RAY_ADDRESS, once API_WAIT_WORKERS nodes
#                   with CPUs are up
#   healthcheck R   exit 0 if role R is healthy here (for the compose healthchecks)
#   anything else   run it (e.g. `tilerender render ...`, `bash`)
#
# Environment: RAY_ADDRESS (head's host:port, default ray-head:6379), RAY_PORT (head, default
# 6379), RAY_NODE_IP (this node's address as other nodes reach it; default: Ray's guess),
# RAY_DASHBOARD (head: true/false, default false), RAY_START_ARGS (more `ray start` flags, e.g.
# fixed ports), RAY_OBJECT_STORE_MEMORY (bytes; default: 80% of /dev/shm when Ray's own default,
# 30% of the memory, does not fit there), RAY_AUTH_MODE and RAY_AUTH_TOKEN (read by Ray: token
# auth on every node), API_PORT (default 8000), API_WAIT_WORKERS (default 1), API_WAIT_TIMEOUT
# (seconds, default 600), TILERENDER_* (the service's settings, docs/api.md).
set -eu

RAY_ADDRESS=${RAY_ADDRESS:-ray-head:6379}
RAY_PORT=${RAY_PORT:-6379}
API_PORT=${API_PORT:-8000}

node_ip() {
    if [ -n "${RAY_NODE_IP:-}" ]; then echo "--node-ip-address=$RAY_NODE_IP"; fi
}

# Ray's object store lives in /dev/shm only if it fits there (else it falls back to slower disk):
# a container's /dev/shm is small (compose's shm_size), so size the store to it.
object_store() {
    if [ -n "${RAY_OBJECT_STORE_MEMORY:-}" ]; then
        echo "--object-store-memory=$RAY_OBJECT_STORE_MEMORY"
        return
    fi
    python -c '
import os
shm = os.statvfs("/dev/shm")
shm = shm.f_frsize * shm.f_bavail
ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
if 0.3 * ram > 0.9 * shm:  # Ray default: 30% of the memory
    print(f"--object-store-memory={int(0.8 * shm)}")
' 2>/dev/null || true
}

wait_for_workers() {
    python - "${API_WAIT_WORKERS:-1}" "${API_WAIT_TIMEOUT:-600}" <<'EOF'
import logging, sys, time

import ray

want, timeout = int(sys.argv[1]), float(sys.argv[2])
ray.init(address="auto", logging_level=logging.ERROR, log_to_driver=False)
deadline = time.monotonic() + timeout
while True:
    nodes = [n for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU", 0) > 0]
    if len(nodes) >= want:
        print(f"entrypoint: {len(nodes)} Ray node(s) with CPUs are up", file=sys.stderr)
        break
    if time.monotonic() > deadline:
        print(f"entrypoint: {len(nodes)} of {want} Ray node(s) with CPUs after {timeout:g} s",
              file=sys.stderr)
        sys.exit(1)
    time.sleep(1)
ray.shutdown()
EOF
}

healthy() {
    case "$1" in
        head) ray health-check --address "127.0.0.1:$RAY_PORT" >/dev/null 2>&1 ;;
        worker)  # this node's raylet runs (it exits when it loses the head)
            python -c '
import os, sys
def name(pid):
    try:
        with open(f"/proc/{pid}/comm") as f:
            return f.read().strip()
    except OSError:  # it ended meanwhile
        return ""
sys.exit(not any(name(p) == "raylet" for p in os.listdir("/proc") if p.isdigit()))'
            ;;
        api)
            python -c '
import sys, urllib.request
urllib.request.urlopen(f"http://127.0.0.1:{sys.argv[1]}/readyz", timeout=5)' "$API_PORT" \
                >/dev/null 2>&1
            ;;
        *)
            echo "healthcheck: unknown role '$1'" >&2
            return 2
            ;;
    esac
}

role=${1:-help}
[ $# -gt 0 ] && shift
case "$role" in
    head)
        # shellcheck disable=SC2046,SC2086
        exec ray start --head --port="$RAY_PORT" --num-cpus="${RAY_HEAD_CPUS:-0}" \
            --include-dashboard="${RAY_DASHBOARD:-false}" --dashboard-host=0.0.0.0 \
            --disable-usage-stats $(object_store) $(node_ip) ${RAY_START_ARGS:-} --block "$@"
        ;;
    worker)
        # shellcheck disable=SC2046,SC2086
        exec ray start --address="$RAY_ADDRESS" \
            ${RAY_WORKER_CPUS:+--num-cpus="$RAY_WORKER_CPUS"} \
            $(object_store) $(node_ip) ${RAY_START_ARGS:-} --block "$@"
        ;;
    api)
        # A Ray driver needs a raylet on its own machine: this one offers no CPUs, so no tracer
        # is placed here.
        # shellcheck disable=SC2046,SC2086
        ray start --address="$RAY_ADDRESS" --num-cpus=0 $(object_store) $(node_ip) \
            ${RAY_START_ARGS:-} >&2
        if [ "${API_WAIT_WORKERS:-1}" -gt 0 ]; then wait_for_workers; fi
        exec tilerender serve --host 0.0.0.0 --port "$API_PORT" --ray-address "$RAY_ADDRESS" "$@"
        ;;
    healthcheck)
        healthy "${1:?usage: healthcheck head|worker|api}"
        ;;
    help | -h | --help)
        sed -n '2,18p' "$0" | sed 's/^# \{0,1\}//'
        ;;
    *)
        exec "$role" "$@"
        ;;
esac
