#!/usr/bin/env bash
# Fetch a libLLVM for Mitsuba's llvm_ad_rgb variant (used by bench/cornell.py) into .cache/llvm.
#
# Dr.Jit's LLVM backend needs a libLLVM that can select `fminimum`; an older system libLLVM
# aborts with "LLVM ERROR: Cannot select: ... fminimum". This downloads Debian's libllvm19
# package with apt-get (no root needed) and unpacks it, without installing anything:
#
#   bench/get_libllvm.sh          # prints the library's path
#
# Idempotent: does nothing when the library is already there. bench/cornell.py looks for it in
# .cache/llvm/root/usr/lib/*/libLLVM.so.* unless DRJIT_LIBLLVM_PATH is set.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGE=libllvm19
DEST=.cache/llvm

find_library() {
    [ -d "$DEST/root/usr/lib" ] || return 0
    find "$DEST/root/usr/lib" -name 'libLLVM.so.*' -type f | sort | tail -n 1
}

library=$(find_library)
if [ -z "$library" ]; then
    mkdir -p "$DEST"
    if ! ls "$DEST/${PACKAGE}"_*.deb >/dev/null 2>&1; then
        (cd "$DEST" && apt-get download "$PACKAGE" >&2) || {
            echo "error: 'apt-get download $PACKAGE' failed (try 'apt-get update' first)" >&2
            exit 1
        }
    fi
    deb=$(ls "$DEST/${PACKAGE}"_*.deb | sort | tail -n 1)
    dpkg-deb -x "$deb" "$DEST/root"
    library=$(find_library)
    if [ -z "$library" ]; then
        echo "error: $deb holds no libLLVM.so.*" >&2
        exit 1
    fi
fi
echo "$PWD/$library"
