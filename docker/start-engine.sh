#!/usr/bin/env bash
# Start a private Docker engine on a Debian machine that has none (no daemon, no systemd unit),
# from Debian's own packages, without installing them system-wide.
#
#   eval "$(docker/start-engine.sh)"     start it (or find one that answers) and point
#                                        DOCKER_HOST at it; prints the export line on stdout
#   docker/start-engine.sh stop          stop the engine this script started
#   docker/start-engine.sh status        say whether it runs
#
# Needs root and apt (Debian 12 or newer). `apt-get download docker.io containerd runc tini` are
# unpacked with `dpkg-deb -x` under ENGINE_DIR and dockerd runs from there with its own data
# root, exec root and socket, so it touches nothing of a Docker installed later. Only iptables
# is installed system-wide (dockerd's bridge network needs it). The downloads, the unpacked tree
# and the engine's images stay in ENGINE_DIR, so a second start takes a few seconds and a
# rebuild reuses its layers. Delete ENGINE_DIR (after `stop`) to start over from scratch.
#
# Environment: TILERENDER_ENGINE_DIR (default ~/.cache/tilerender/docker-engine),
# DOCKER_MTU (default: the MTU of the default route's interface; containers behind a tunnel
# with a smaller MTU than 1500 otherwise stall on large TLS downloads).
set -euo pipefail

ENGINE_DIR=${TILERENDER_ENGINE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/tilerender/docker-engine}
ROOT=$ENGINE_DIR/root
SOCKET=$ENGINE_DIR/docker.sock
PIDFILE=$ENGINE_DIR/dockerd.pid
LOG=$ENGINE_DIR/dockerd.log
PACKAGES=(docker.io containerd runc tini)
START_TIMEOUT=60

say() { echo "start-engine: $*" >&2; }
die() {
    say "error: $*"
    exit 1
}

docker_cli() {
    if command -v docker >/dev/null; then command -v docker; else echo "$ROOT/usr/bin/docker"; fi
}

answers() { [ -x "$(docker_cli)" ] && "$(docker_cli)" ${1:+-H "$1"} info >/dev/null 2>&1; }

exports() {
    echo "export DOCKER_HOST=unix://$SOCKET"
    command -v docker >/dev/null || echo "export PATH=$ROOT/usr/bin:\$PATH"
}

# Run a command with its output in ENGINE_DIR/setup.log, shown only if it fails.
quietly() {
    mkdir -p "$ENGINE_DIR"
    "$@" >"$ENGINE_DIR/setup.log" 2>&1 || {
        local code=$?
        tail -n 30 "$ENGINE_DIR/setup.log" >&2
        return $code
    }
}

engine_path() { echo "$ROOT/usr/bin:$ROOT/usr/sbin:$PATH"; }

running_pid() {
    [ -f "$PIDFILE" ] || return 1
    local pid
    pid=$(cat "$PIDFILE")
    [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null && echo "$pid"
}

unpack_engine() {
    [ -x "$ROOT/usr/sbin/dockerd" ] && return
    command -v apt-get >/dev/null || die "no apt-get: install Docker from your distribution instead"
    mkdir -p "$ENGINE_DIR/debs"
    if ! apt-cache policy docker.io | grep -q 'Candidate: [0-9]'; then
        say "apt-get update"
        quietly apt-get update
    fi
    say "downloading ${PACKAGES[*]} into $ENGINE_DIR/debs"
    (cd "$ENGINE_DIR/debs" && quietly apt-get download "${PACKAGES[@]}")
    rm -rf "$ROOT.partial"
    for deb in "$ENGINE_DIR"/debs/*.deb; do
        dpkg-deb -x "$deb" "$ROOT.partial"
    done
    mv "$ROOT.partial" "$ROOT"
}

ensure_iptables() {
    command -v iptables >/dev/null && return
    say "apt-get install iptables (dockerd's bridge network needs it)"
    export DEBIAN_FRONTEND=noninteractive
    quietly apt-get install -y iptables ||
        { quietly apt-get update && quietly apt-get install -y iptables; }
}

default_mtu() {
    local dev
    dev=$(ip route show default 2>/dev/null |
        awk '{for (i = 1; i < NF; i++) if ($i == "dev") print $(i + 1); exit}')
    if [ -n "$dev" ] && [ -r "/sys/class/net/$dev/mtu" ]; then
        cat "/sys/class/net/$dev/mtu"
    else
        echo 1500
    fi
}

start() {
    if [ -z "${DOCKER_HOST:-}" ] && answers ""; then
        say "a Docker engine already answers on the default socket; using it"
        return
    fi
    if running_pid >/dev/null && answers "unix://$SOCKET"; then
        say "the engine under $ENGINE_DIR already runs (pid $(running_pid))"
        exports
        return
    fi
    [ "$(id -u)" = 0 ] || die "starting dockerd needs root"
    ensure_iptables
    unpack_engine
    mkdir -p "$ENGINE_DIR/data" "$ENGINE_DIR/exec"
    local mtu=${DOCKER_MTU:-$(default_mtu)}
    say "starting dockerd (socket $SOCKET, MTU $mtu, log $LOG)"
    PATH=$(engine_path) setsid nohup dockerd \
        --data-root "$ENGINE_DIR/data" \
        --exec-root "$ENGINE_DIR/exec" \
        --pidfile "$PIDFILE" \
        -H "unix://$SOCKET" \
        --mtu "$mtu" \
        >"$LOG" 2>&1 </dev/null &
    local deadline=$((SECONDS + START_TIMEOUT))
    until answers "unix://$SOCKET"; do
        if [ $SECONDS -ge $deadline ]; then
            tail -n 20 "$LOG" >&2
            die "dockerd did not answer within ${START_TIMEOUT}s (log: $LOG)"
        fi
        sleep 0.5
    done
    local version
    version=$("$(docker_cli)" -H "unix://$SOCKET" version --format '{{.Server.Version}}')
    say "dockerd $version is up"
    exports
}

stop() {
    local pid
    if ! pid=$(running_pid); then
        say "no engine of ours runs (pidfile $PIDFILE)"
        return
    fi
    say "stopping dockerd (pid $pid)"
    kill -TERM "$pid"
    for _ in $(seq 60); do
        if ! kill -0 "$pid" 2>/dev/null; then
            unmount_leftovers
            say "stopped"
            return
        fi
        sleep 0.5
    done
    die "dockerd (pid $pid) is still running after 30 s"
}

# dockerd leaves its default network namespace mounted under the exec root; unmount whatever is
# still mounted under ENGINE_DIR, so that the directory can be deleted.
unmount_leftovers() {
    awk -v dir="$ENGINE_DIR/" 'index($2, dir) == 1 {print $2}' /proc/mounts | sort -r |
        while read -r mountpoint; do umount "$mountpoint" 2>/dev/null || true; done
}

status() {
    local pid
    if pid=$(running_pid) && answers "unix://$SOCKET"; then
        say "running (pid $pid): export DOCKER_HOST=unix://$SOCKET"
    else
        say "not running"
        return 1
    fi
}

case "${1:-start}" in
    start) start ;;
    stop) stop ;;
    status) status ;;
    *)
        sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//' >&2
        exit 2
        ;;
esac
