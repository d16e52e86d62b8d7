#!/usr/bin/env bash
# Primary-ray throughput on a real GPU: prints the adapter, Mrays/s, steps per ray, nodes per
# block and the share of busy lanes of `dcrt bench rays` on the rm and assembly generators at
# 1024x1024, both block stores.
#
#   scripts/gpu-bench.sh [DCRT_BINARY] [extra dcrt bench rays options...]
#
# Needs only the dcrt binary and a Vulkan loader with a driver. Without a binary argument it
# uses target/release/dcrt, building it first (without MPI, which a GPU box may lack) when cargo
# is at hand. ADAPTER picks an adapter by part of its name (default: the best GPU wgpu finds);
# TRIANGLES and SIZE change the scene (defaults 1000000 and 1024).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bin="${1:-}"
[ $# -gt 0 ] && shift
if [ -z "$bin" ]; then
    bin="$root/target/release/dcrt"
    if [ ! -x "$bin" ]; then
        command -v cargo >/dev/null || { echo "gpu-bench: no $bin and no cargo to build it" >&2; exit 1; }
        (cd "$root" && cargo build --release --no-default-features --bin dcrt)
    fi
fi
[ -x "$bin" ] || { echo "gpu-bench: $bin is not an executable" >&2; exit 1; }
tris="${TRIANGLES:-1000000}"
size="${SIZE:-1024}"
adapter=()
[ -n "${ADAPTER:-}" ] && adapter=(--adapter "$ADAPTER")
for gen in rm assembly; do
    json="$("$bin" bench rays --generator "$gen" --triangles "$tris" --width "$size" --height "$size" \
        --stores --json "${adapter[@]}" "$@")"
    # The JSON is printed pretty; pick the figures without needing jq or python.
    echo "$json" | awk -v gen="$gen" '
        /"adapter":/ { sub(/^[^:]*: /, ""); sub(/,$/, ""); printf "adapter   %s\n", $0 }
        /"store":/ { gsub(/[",]/, "", $2); store = $2 }
        /"mode":/ { gsub(/[",]/, "", $2); mode = $2 }
        /"mrays_per_s":/ && store != "" { gsub(/,/, "", $2); m = $2 }
        /"steps_per_ray":/ && store != "" { gsub(/,/, "", $2); s = $2 }
        /"nodes_per_node_block":/ && store != "" { gsub(/,/, "", $2); n = $2 }
        /"lane_use":/ && store != "" { gsub(/,/, "", $2); l = $2 }
        /"shade_share":/ && store != "" {
            printf "%-9s %-8s %-5s %10.3f Mrays/s %8.1f steps/ray %6.2f nodes/block %5.1f%% lanes busy\n", gen, store, mode, m, s, n, 100 * l
        }'
done
