#!/usr/bin/env bash
# Fault rounds and blocks fetched per frame of a distributed-cache orbit: `dcrt bench job` (the
# render path, with switches such as --faults) of a prepared model as one rank of virtual ranks,
# one line per frame, then the means of the warm frames (from frame 1) and of those sized by the
# frame before (from frame 2). Fault rounds and blocks do not depend on the machine's load, so
# this compares builds or settings without pairing.
#
#   scripts/orbit-rounds.sh DCRT MODEL.dcb [dcrt bench job options...]
#   e.g. scripts/orbit-rounds.sh target/release/dcrt rm3.dcb --cache 1/32 --replicate-blocks nodes
#
# Defaults (each overridden by the same option given after the model): --virtual-ranks 8
# --rank 0 --cache-map lru --frames 8. Needs python3.
set -euo pipefail
[ $# -ge 2 ] || { sed -n '2,11p' "$0" >&2; exit 2; }
bin="$1" model="$2"
shift 2
[ -x "$bin" ] || { echo "orbit-rounds: $bin is not an executable" >&2; exit 1; }
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
given() {
    local o
    for o in "${args[@]}"; do
        case "$o" in "$1" | "$1"=*) return 0 ;; esac
    done
    return 1
}
args=("$@")
for d in "--virtual-ranks 8" "--rank 0" "--cache-map lru" "--frames 8"; do
    read -r opt value <<<"$d"
    given "$opt" || args+=("$opt" "$value")
done
"$bin" bench job "$model" "${args[@]}" \
    -o "$tmp/frame.png" --stats "$tmp/stats.json" >"$tmp/log" 2>&1 || { cat "$tmp/log" >&2; exit 1; }
python3 - "$tmp/stats.json" <<'PY'
import json, sys
frames = json.load(open(sys.argv[1]))["frames"]
for f in frames:
    s = f["stats"]
    print("frame %2d: %6.0f ms, %3d fault rounds, %6d blocks fetched, %6d distinct"
          % (f["frame"], f["frame_ms"], s["fault_rounds"], s["fetched_blocks"], s["distinct_blocks"]))
for first in (1, 2):
    warm = [f["stats"] for f in frames if f["frame"] >= first]
    if warm:
        n = len(warm)
        print("frames %d-%d: %.1f fault rounds, %.0f blocks fetched a frame"
              % (first, frames[-1]["frame"], sum(s["fault_rounds"] for s in warm) / n,
                 sum(s["fetched_blocks"] for s in warm) / n))
PY
