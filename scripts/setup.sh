#!/usr/bin/env bash
# Installs what dcrt needs on Debian: lavapipe (Vulkan on the CPU), libclang (bindgen for the mpi
# crate), Open MPI, DejaVu fonts (the text of `--legend` and charts), Embree 3 (the peer of
# `bench rays --peer embree`, which a test runs), Chromium and Firefox ESR
# with their WebDrivers (geckodriver built by cargo) and a Python venv holding selenium
# (.view-venv: the browser tests of `dcrt view`), and cargo-nextest. On Debian 12, lavapipe comes from bookworm-backports (Mesa 25 rather than the
# release's 22.3.6: the same images, faster kernels; DCRT_SYSTEM_MESA=1 keeps the release's).
# Installs only what is missing; safe to run again.
set -euo pipefail
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"

packages=(mesa-vulkan-drivers libvulkan1 vulkan-tools libclang-dev openmpi-bin libopenmpi-dev pkg-config fonts-dejavu-core
  libembree-dev gcc chromium chromium-driver firefox-esr python3-venv)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  $sudo apt-get update -q
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

if [ -z "${DCRT_SYSTEM_MESA:-}" ] && grep -qx 'VERSION_CODENAME=bookworm' /etc/os-release; then
  have=$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || echo 0)
  if ! dpkg --compare-versions "$have" ge 25; then
    echo "setup: installing lavapipe from bookworm-backports (Mesa $have installed)"
    echo "deb http://deb.debian.org/debian bookworm-backports main" |
      $sudo tee /etc/apt/sources.list.d/bookworm-backports.list >/dev/null
    $sudo apt-get update -q
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends \
      -t bookworm-backports mesa-vulkan-drivers
  fi
fi

if ! cargo nextest --version >/dev/null 2>&1; then
  echo "setup: installing cargo-nextest"
  cargo install cargo-nextest --locked
fi

# Firefox's WebDriver: not packaged by Debian 12; Mozilla publishes it on crates.io.
GECKODRIVER_VERSION=0.37.1
if ! geckodriver --version 2>/dev/null | grep -q "^geckodriver $GECKODRIVER_VERSION"; then
  echo "setup: installing geckodriver $GECKODRIVER_VERSION"
  cargo install geckodriver --version "$GECKODRIVER_VERSION" --locked
fi

# The browser tests of `dcrt view` (tests/view_browser.py) drive Chromium and Firefox with
# selenium.
SELENIUM_VERSION=4.51.0
root="$(cd "$(dirname "$0")/.." && pwd)"
venv="$root/.view-venv"
if [ ! -x "$venv/bin/python" ] || ! "$venv/bin/python" -c "import selenium, sys; sys.exit(selenium.__version__ != '$SELENIUM_VERSION')" 2>/dev/null; then
  echo "setup: creating $venv with selenium==$SELENIUM_VERSION"
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q "selenium==$SELENIUM_VERSION"
fi
