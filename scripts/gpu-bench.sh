#!/usr/bin/env bash
# dcrt's speed on a real GPU, the figures of docs/benchmarks.md in one run:
#
# 1. rays: per scene (`rm`, `assembly`), BVH node cost (3 and 1), shading mode (cast, ao, path)
#    and block store (texture, buffer) Mrays/s, steps a ray, nodes a node block and the share of
#    busy lanes (`bench rays`);
# 2. dc: the distributed cache's table (`bench dc`: `rm`, rank 0 of 8 virtual ranks, the root
#    block replicated, caches 1/8 and 1/32, every mapping) at each size in DC_SIZES, for a
#    camera turning 3 degrees a frame (a user's) and 120 (the bench's default orbit).
#
#   scripts/gpu-bench.sh [DCRT_BINARY] [extra `bench rays` options...]
#
# Needs only the dcrt binary and a Vulkan loader with a driver. Without a binary argument it
# uses target/release/dcrt, building it first (without MPI, which a GPU box may lack) when cargo
# is at hand. Settings, from the environment:
#   ADAPTER       part of the adapter's name (default: the best GPU wgpu finds)
#   TRIANGLES     triangles of the rays scenes (default 1000000); SIZE their image side (1024)
#   MODES         shading modes of the rays part (default cast,ao,path)
#   NODE_COSTS    the BVH node costs the rays part builds with, side by side (default 3,1)
#   DC_TRIANGLES  triangles of the dc scene (default 677000); DC_SIZES its image sides ("512 1024")
#   DC_FRAMES     frames of each dc orbit, the first cold (default 4)
#   PARTS         which parts run (default "rays dc")
#   OUT           a folder: each bench's JSON and the printed tables are also written there
#   LIMIT         seconds any one bench may run before it is stopped (default 300); a bench that
#                 fails or is stopped is named on stderr, the others still run, and the script
#                 exits 1
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
modes="${MODES:-cast,ao,path}"
node_costs="${NODE_COSTS:-3,1}"
dc_tris="${DC_TRIANGLES:-677000}"
dc_sizes="${DC_SIZES:-512 1024}"
dc_frames="${DC_FRAMES:-4}"
parts="${PARTS:-rays dc}"
limit="${LIMIT:-300}"
out="${OUT:-}"
[ -n "$out" ] && mkdir -p "$out"
adapter=()
[ -n "${ADAPTER:-}" ] && adapter=(--adapter "$ADAPTER")
failed=0

# Saves stdin as $out/$1 when OUT is given, and passes it on.
keep() {
    if [ -n "$out" ]; then tee "$out/$1"; else cat; fi
}

for part in $parts; do
    case "$part" in
    rays | dc) ;;
    *)
        echo "gpu-bench: unknown part '$part' in PARTS (rays, dc)" >&2
        exit 2
        ;;
    esac
done

for part in $parts; do
    case "$part" in
    rays)
        for gen in rm assembly; do
            json="$(timeout "$limit" "$bin" bench rays --generator "$gen" --triangles "$tris" \
                --width "$size" --height "$size" --modes "$modes" --stores \
                --bvh-node-costs "$node_costs" --json "${adapter[@]}" "$@")" || {
                echo "gpu-bench: bench rays on $gen failed or ran past ${limit}s (exit $?)" >&2
                failed=1
                continue
            }
            [ -n "$out" ] && echo "$json" >"$out/rays-$gen.json"
            # The JSON is printed pretty, one key a line: the figures without jq or python.
            echo "$json" | awk -v gen="$gen" '
                /"adapter":/ { sub(/^[^:]*: /, ""); gsub(/^"|",?$/, ""); printf "adapter   %s\n", $0 }
                /"node_cost":/ { gsub(/,/, "", $2); cost = $2 }
                /"store":/ { gsub(/[",]/, "", $2); store = $2 }
                /"mode":/ { gsub(/[",]/, "", $2); mode = $2 }
                /"mrays_per_s":/ && store != "" { gsub(/,/, "", $2); m = $2 }
                /"steps_per_ray":/ && store != "" { gsub(/,/, "", $2); s = $2 }
                /"nodes_per_node_block":/ && store != "" { gsub(/,/, "", $2); n = $2 }
                /"lane_use":/ && store != "" { gsub(/,/, "", $2); l = $2 }
                /"shade_share":/ && store != "" {
                    printf "%-9s node cost %-4g %-8s %-7s %10.3f Mrays/s %8.1f steps/ray %6.2f nodes/block %5.1f%% lanes busy\n", gen, cost, store, mode, m, s, n, 100 * l
                }' | keep "rays-$gen.txt"
        done
        ;;
    dc)
        for s in $dc_sizes; do
            for step in 3 120; do
                echo "dc        rm $dc_tris triangles, ${s}x$s, rank 0 of 8, root replicated, ${step} degrees a frame"
                if ! timeout "$limit" "$bin" bench dc --generator rm --triangles "$dc_tris" --width "$s" \
                    --height "$s" --caches 1/8,1/32 --cache-maps ize,demarle,lru \
                    --replicate-blocks root --frames "$dc_frames" --step "$step" -q "${adapter[@]}" |
                    keep "dc-$s-$step.txt"; then
                    echo "gpu-bench: bench dc at ${s}x$s, $step degrees failed or ran past ${limit}s" >&2
                    failed=1
                fi
            done
        done
        ;;
    esac
done
exit $failed
