#!/usr/bin/env bash
# Installs what dcrt needs on Debian: lavapipe (Vulkan on the CPU), libclang (bindgen for the mpi
# crate), Open MPI, DejaVu fonts (the text of `--legend` and `bench figures`), Chromium and its
# WebDriver with a Python venv holding selenium (.view-venv: the browser test of `dcrt view`), and
# cargo-nextest. Installs only what is missing; safe to run again.
set -euo pipefail

packages=(mesa-vulkan-drivers libvulkan1 vulkan-tools libclang-dev openmpi-bin libopenmpi-dev pkg-config fonts-dejavu-core
  chromium chromium-driver python3-venv)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  $sudo apt-get update -q
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

if ! cargo nextest --version >/dev/null 2>&1; then
  echo "setup: installing cargo-nextest"
  cargo install cargo-nextest --locked
fi

# The browser test of `dcrt view` (tests/view_browser.py) drives Chromium with selenium.
SELENIUM_VERSION=4.51.0
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/.view-venv"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import selenium, sys; sys.exit(selenium.__version__ != '$SELENIUM_VERSION')" 2>/dev/null; then
  echo "setup: creating $venv with selenium==$SELENIUM_VERSION"
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q "selenium==$SELENIUM_VERSION"
fi
