#!/usr/bin/env bash
# Traced mpirun runs at several rank counts and transports, for checking `dcrt simulate`:
# writes OUT/<transport>-k<K>-r<run>/ (a trace directory per run); scripts/simulate-table.py
# then tabulates `dcrt simulate` on them (own K, and from K = 4 to the others).
# Usage: scripts/simulate-validate.sh DCRT OUT [RUNS] [KS]
set -euo pipefail
dcrt=${1:?usage: simulate-validate.sh DCRT OUT [RUNS] [KS]}
out=${2:?usage: simulate-validate.sh DCRT OUT [RUNS] [KS]}
runs=${3:-3}
ks=${4:-"4 5 6"}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
mkdir -p "$out"
cat >"$out/rm.toml" <<'TOML'
[image]
width = 128
height = 96

[[mesh]]
generator = "rm"
triangles = 50000
TOML
"$dcrt" prepare "$out/rm.toml" -o "$out/rm.dcb" >/dev/null
for r in $(seq 1 "$runs"); do
  for k in $ks; do
    for tr in shm tcp; do
      mca=()
      [ "$tr" = tcp ] && mca=(--mca btl tcp,self --mca osc pt2pt)
      d="$out/$tr-k$k-r$r"
      rm -rf "$d"
      timeout -k 5 300 mpirun --oversubscribe "${mca[@]}" -n "$k" "$dcrt" render "$out/rm.dcb" \
        -o "$out/t.png" --trace "$d" --cache 1/8 --tile 32 --min-tile 8 --frames 10 \
        >/dev/null 2>"$out/$tr-k$k-r$r.err"
      echo "$tr k=$k run $r done"
    done
  done
done
