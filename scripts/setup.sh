#!/usr/bin/env bash
# Installs what dcrt needs on Debian: lavapipe (Vulkan on the CPU), libclang (bindgen for the mpi
# crate), Open MPI, DejaVu fonts (the text of `--legend` and `bench figures`), and
# cargo-nextest. Installs only what is missing; safe to run again.
set -euo pipefail

packages=(mesa-vulkan-drivers libvulkan1 vulkan-tools libclang-dev openmpi-bin libopenmpi-dev pkg-config fonts-dejavu-core)
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
