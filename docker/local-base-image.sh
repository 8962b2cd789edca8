#!/usr/bin/env bash
# Make a base image without a registry: a minimal Debian 12 root file system with Python 3.11
# (debootstrap --variant=minbase from Debian's mirror), imported into the engine as
# local/debian-python:bookworm. It stands in for the official python:3.11-slim image where
# Docker Hub cannot be reached; build with --build-arg BASE_IMAGE=local/debian-python:bookworm.
#
#   docker/local-base-image.sh           import it (no-op if the engine already has it)
#
# Needs root, apt and a running engine (docker/start-engine.sh). debootstrap comes from
# `apt-get download` like the engine; the root file system is kept as a tarball under
# TILERENDER_ENGINE_DIR (default ~/.cache/tilerender/docker-engine), so importing it again into a
# fresh engine takes seconds.
set -euo pipefail

ENGINE_DIR=${TILERENDER_ENGINE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/tilerender/docker-engine}
IMAGE=${LOCAL_BASE_IMAGE:-local/debian-python:bookworm}
SUITE=bookworm
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
TARBALL=$ENGINE_DIR/base/debian-python-$SUITE.tar
TOOLS=$ENGINE_DIR/debootstrap

say() { echo "local-base-image: $*" >&2; }

if docker image inspect "$IMAGE" >/dev/null 2>&1; then
    say "$IMAGE is already there"
    exit 0
fi

if [ ! -f "$TARBALL" ]; then
    [ "$(id -u)" = 0 ] || { say "error: debootstrap needs root"; exit 1; }
    if [ ! -x "$TOOLS/usr/sbin/debootstrap" ]; then
        mkdir -p "$ENGINE_DIR/debs"
        (cd "$ENGINE_DIR/debs" && apt-get download -q debootstrap) >"$ENGINE_DIR/setup.log" 2>&1 ||
            { tail -n 20 "$ENGINE_DIR/setup.log" >&2; exit 1; }
        dpkg-deb -x "$ENGINE_DIR"/debs/debootstrap_*.deb "$TOOLS"
    fi
    rootfs=$(mktemp -d "${TMPDIR:-/tmp}/rootfs.XXXXXX")
    trap 'rm -rf "$rootfs"' EXIT
    say "debootstrap --variant=minbase $SUITE (about 30 s)"
    DEBOOTSTRAP_DIR=$TOOLS/usr/share/debootstrap "$TOOLS/usr/sbin/debootstrap" \
        --variant=minbase --include=python3,python3-venv,ca-certificates \
        "$SUITE" "$rootfs" "$MIRROR" >"$ENGINE_DIR/debootstrap.log" 2>&1 ||
        { tail -n 20 "$ENGINE_DIR/debootstrap.log" >&2; exit 1; }
    rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/lib/apt/lists/*
    mkdir -p "$(dirname "$TARBALL")"
    tar -C "$rootfs" -cf "$TARBALL.partial" .
    mv "$TARBALL.partial" "$TARBALL"
fi

say "importing $TARBALL as $IMAGE"
docker import \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' \
    --change 'CMD ["/bin/bash"]' \
    "$TARBALL" "$IMAGE" >/dev/null
say "done: $IMAGE"
