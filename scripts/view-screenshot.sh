#!/usr/bin/env bash
# The README's picture of `dcrt view`: the page in headless Chromium (tests/view_browser.py), a
# left drag, then the refined frame. Usage: [LAUNCH="mpirun -n 4"] scripts/view-screenshot.sh
# [OUT.png] [dcrt view options...]; needs scripts/setup.sh's Chromium and .view-venv, and a
# release build. LAUNCH starts the view under a launcher (the README's: mpirun -n 4, --cache 1/4).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-docs/figures/view.png}
shift || true
bin=target/release/dcrt
[ -x "$bin" ] || cargo build --release
log=$(mktemp)
trap 'kill "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true; rm -f "$log"' EXIT
# shellcheck disable=SC2086
${LAUNCH:-} "$bin" view scenes/rm.toml --port 0 --width 800 --height 520 --mode ao --spp 16 "$@" 2>"$log" &
pid=$!
for _ in $(seq 600); do
  url=$(sed -n 's/^view: open \([^ ]*\).*/\1/p' "$log")
  [ -n "$url" ] && break
  sleep 0.5
done
[ -n "${url:-}" ] || { cat "$log"; echo "view-screenshot: the view printed no URL" >&2; exit 1; }
.view-venv/bin/python tests/view_browser.py "$url" chromium "$(command -v chromedriver)" "$(command -v chromium)" "$out" 1000x660
echo "view-screenshot: wrote $out"
