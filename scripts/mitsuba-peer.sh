#!/usr/bin/env bash
# Renders a scene that `dcrt bench shading --peer mitsuba` wrote into DIR with Mitsuba 3
# (scripts/mitsuba-peer.py). On first use it makes its own Python venv in .mitsuba-venv (git
# ignored) with a pinned Mitsuba from PyPI, and installs Debian's libllvm19 for the llvm_ad_rgb
# variant if it is missing. Usage: scripts/mitsuba-peer.sh DIR
set -euo pipefail

MITSUBA_VERSION=3.9.1
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(dirname "$here")"
venv="$root/.mitsuba-venv"

[ $# -eq 1 ] || { echo "usage: $0 DIR" >&2; exit 2; }

if ! dpkg-query -W -f='${Status}' libllvm19 2>/dev/null | grep -q "install ok installed"; then
  echo "mitsuba-peer: installing libllvm19" >&2
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  $sudo apt-get update -q >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends libllvm19 >&2
fi
llvm="$(dpkg -L libllvm19 | grep -E '/libLLVM[^/]*\.so[.0-9]*$' | head -n 1)"
[ -n "$llvm" ] && [ -e "$llvm" ] || { echo "mitsuba-peer: no libLLVM shared object in libllvm19" >&2; exit 1; }
export DRJIT_LIBLLVM_PATH="$llvm"

if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import mitsuba, sys; sys.exit(mitsuba.__version__ != '$MITSUBA_VERSION')" 2>/dev/null; then
  echo "mitsuba-peer: creating $venv with mitsuba==$MITSUBA_VERSION" >&2
  python3 -m venv "$venv" >&2
  "$venv/bin/pip" install -q "mitsuba==$MITSUBA_VERSION" >&2
fi

exec "$venv/bin/python" "$here/mitsuba-peer.py" "$1"
