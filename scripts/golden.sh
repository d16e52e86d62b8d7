#!/usr/bin/env bash
# Output bytes of every shipped scene in every shading mode, of distributed-cache renders (virtual
# ranks, a .dcb) and of cluster renders under mpirun: a manifest of SHA-256 sums, to show that a
# change which should change no image changed none.
#
#   scripts/golden.sh DCRT_BINARY OUT_DIR            # renders, writes OUT_DIR/manifest.txt
#   diff old/manifest.txt new/manifest.txt           # empty when every byte is the same
#
# Small images keep it to a few minutes on lavapipe.
set -euo pipefail
bin=$(realpath "$1")
out=$2
mkdir -p "$out"
out=$(realpath "$out")
cd "$(dirname "$0")/.."
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
size=(--width 48 --height 40)
run() { echo "+ $*" >&2; timeout 600 "$@" 2>>"$out/log.txt"; }

for scene in scenes/*.toml; do
  s=$(basename "$scene" .toml)
  for mode in cast shadows ao path; do
    run "$bin" render "$scene" "${size[@]}" --mode "$mode" --spp 2 --ao-rays 4 \
      -o "$out/$s-$mode.png" --exr "$out/$s-$mode.exr" --aov depth,id,normal
  done
done

# The distributed cache in one process: from a scene and from a block file.
run "$bin" prepare scenes/rm.toml -o "$out/rm.dcb"
run "$bin" render scenes/default.toml "${size[@]}" --virtual-ranks 3 --rank 1 --cache 64lines \
  --cache-map demarle --frames 2 -o "$out/default-dc.png"
run "$bin" render "$out/rm.dcb" "${size[@]}" --virtual-ranks 4 --rank 2 --cache 1/8 --frames 2 \
  --mode ao --spp 2 --ao-rays 4 -o "$out/rm-dc.png" --exr "$out/rm-dc.exr" --aov depth,id
run "$bin" render "$out/rm.dcb" "${size[@]}" --virtual-ranks 8 --cache 1lines --mode path \
  -o "$out/rm-dc1.png"

# Cluster mode: replicated and with the distributed cache.
run mpirun --oversubscribe -n 3 "$bin" render "$out/rm.dcb" "${size[@]}" --mode shadows \
  -o "$out/rm-k3.png"
run mpirun --oversubscribe -n 5 "$bin" render "$out/rm.dcb" "${size[@]}" --cache 1/8 --frames 2 \
  --tile 16 --min-tile 8 -o "$out/rm-k5dc.png" --exr "$out/rm-k5dc.exr" --aov depth,id,normal

(cd "$out" && sha256sum ./*.png ./*.exr ./*.dcb | sort -k2) > "$out/manifest.txt"
echo "golden: $(wc -l < "$out/manifest.txt") files in $out/manifest.txt"
