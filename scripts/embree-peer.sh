#!/usr/bin/env bash
# The Embree peer of `dcrt bench rays --peer embree`: traces the camera rays dcrt wrote to DIR with
# native Embree 3 (Debian's libembree-dev, installed here on first use) and prints one JSON line.
# The harness is compiled on first use, and again when its source changes, into a git-ignored
# folder next to this script. Not part of dcrt's build.
set -euo pipefail
if [ $# -ne 1 ]; then
    echo "usage: $0 DIR (mesh.bin and camera.txt written by dcrt bench rays --peer embree)" >&2
    exit 2
fi
here="$(cd "$(dirname "$0")" && pwd)"
if [ ! -f /usr/include/embree3/rtcore.h ]; then
    echo "embree peer: installing libembree-dev" >&2
    sudo=""
    # Never a password prompt from a benchmark or a test: scripts/setup.sh installs it otherwise.
    [ "$(id -u)" -ne 0 ] && sudo="sudo -n"
    $sudo apt-get update -qq >&2
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq libembree-dev >&2
fi
out="$here/.embree-peer"
bin="$out/embree_peer"
mkdir -p "$out"
if [ ! -x "$bin" ] || [ "$here/embree_peer.c" -nt "$bin" ]; then
    gcc -O3 -march=native -std=c11 -D_GNU_SOURCE -o "$bin.tmp" "$here/embree_peer.c" -lembree3 -lpthread -lm >&2
    mv "$bin.tmp" "$bin"
fi
exec "$bin" "$1"
