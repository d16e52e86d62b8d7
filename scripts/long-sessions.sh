#!/usr/bin/env bash
# The long-session figures, for one or more dcrt binaries side by side (say a release before and
# after a change): the soak slope of `bench soak` (rm 677k at 64x64, rank 1 of 4 virtual ranks
# with a 1/32 cache), the RSS of a 700-frame render replicated and cached, the time from a
# SIGSTOP of render rank 3 to the end of a 4-rank mpirun job (shared memory, TCP, UCX), and what
# SIGTERM leaves of a one-process render and of an mpirun job.
#
#   scripts/long-sessions.sh [--frames N] DCRT [DCRT ...]
#
# Everything runs in a scratch directory; results go to stdout. Takes about 5 minutes a binary
# at the default 3000 soak frames on a 2-core machine.
set -euo pipefail
frames=3000
if [ "${1:-}" = "--frames" ]; then
  frames=$2
  shift 2
fi
[ $# -ge 1 ] || { echo "usage: $0 [--frames N] DCRT [DCRT ...]" >&2; exit 2; }
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cat > "$work/big.toml" <<'EOF'
[[mesh]]
generator = "rm"
triangles = 677000
seed = 3
EOF
cat > "$work/small.toml" <<'EOF'
[[mesh]]
generator = "rm"
triangles = 20000
seed = 3
EOF
first=$(realpath "$1")
"$first" prepare "$work/big.toml" -o "$work/big.dcb" -q
"$first" prepare "$work/small.toml" -o "$work/small.dcb" -q

# RSS (KiB) of a render when it reports frame 70 and its last frame (699).
rss_of() {
  local out=$1
  shift
  local fifo="$work/fifo"
  rm -f "$fifo"; mkfifo "$fifo"
  "$@" 2> "$fifo" >/dev/null &
  local pid=$! at70="?" at699="?"
  while IFS= read -r line; do
    case "$line" in
      "frame 70:"*) at70=$(awk '/VmRSS/ {print $2}' "/proc/$pid/status") ;;
      "frame 699:"*) at699=$(awk '/VmRSS/ {print $2}' "/proc/$pid/status") ;;
    esac
  done < "$fifo"
  wait "$pid" || true
  echo "$at70 -> $at699" > "$out"
}

# Seconds from SIGSTOP of world rank 3 (after 6 s) to the end of the job, and its error line.
stop_rank() {
  local bin=$1 dir=$2
  shift 2
  mkdir -p "$dir"
  timeout -k 5 120 mpirun --oversubscribe "$@" -n 4 "$bin" render "$work/small.dcb" \
    --cache 1/8 --width 64 --height 64 --frames 100000 -o "$dir/f.png" --timeout 5 \
    > "$dir/log" 2>&1 &
  local job=$!
  sleep 6
  for p in $(pgrep -f "$dir/f.png" || true); do
    if tr '\0' '\n' < "/proc/$p/environ" 2>/dev/null | grep -qx OMPI_COMM_WORLD_RANK=3; then
      kill -STOP "$p"
    fi
  done
  local t0 t1
  t0=$(date +%s.%N)
  wait "$job" || true
  t1=$(date +%s.%N)
  pkill -CONT -f "$dir/f.png" 2>/dev/null || true
  printf '%.1f s; %s' "$(echo "$t1 - $t0" | bc)" \
    "$(grep -m1 -o 'error: no [^:]*: it has stopped, hung or died' "$dir/log" || echo 'no rank named')"
}

# What SIGTERM after a few seconds leaves: frames on disk and the message.
sigterm() {
  local dir=$1
  shift
  mkdir -p "$dir"
  "$@" -o "$dir/f.png" > "$dir/log" 2>&1 &
  local pid=$!
  sleep 6
  kill -TERM "$pid"
  wait "$pid" || true
  printf '%s frames left; %s' "$(ls "$dir" | grep -c '^f_.*png$' || true)" \
    "$( (grep -m1 -o 'interrupted by SIG.*kept.*' "$dir/log" || grep -m1 -o 'interrupted by SIG.*' "$dir/log") | cut -c1-100)"
}

i=0
for bin in "$@"; do
  bin=$(realpath "$bin")
  i=$((i + 1))
  echo "== $i: $bin"
  "$bin" bench soak "$work/big.toml" --frames "$frames" --width 64 --height 64 --cache 1/32 \
    --virtual-ranks 4 --rank 1 -q --json > "$work/soak$i.json"
  python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print('soak: %d frames, RSS %.1f -> %.1f MiB, slope %.0f bytes a frame, GPU objects %s' % (r['frames'], r['rss_start_mib'], r['rss_end_mib'], r['bytes_per_frame'], 'not counted' if 'gpu_objects_end' not in r else 'flat' if r['gpu_objects_warm'] == r['gpu_objects_end'] else 'GREW'))" "$work/soak$i.json"
  rm -rf "$work/r"; mkdir "$work/r"
  rss_of "$work/rss" "$bin" render "$work/big.dcb" --width 64 --height 64 --frames 700 -o "$work/r/f.png"
  echo "render 700 frames replicated: RSS $(cat "$work/rss") KiB (frame 70, frame 699)"
  rm -rf "$work/r"; mkdir "$work/r"
  rss_of "$work/rss" "$bin" render "$work/big.dcb" --width 64 --height 64 --frames 700 \
    -o "$work/r/f.png" --virtual-ranks 4 --rank 1 --cache 1/32
  echo "render 700 frames, 1/32 cache: RSS $(cat "$work/rss") KiB (frame 70, frame 699)"
  rm -rf "$work/r"
  echo "SIGSTOP rank 3, shared memory: $(stop_rank "$bin" "$work/s$i-shm")"
  echo "SIGSTOP rank 3, TCP/pt2pt: $(stop_rank "$bin" "$work/s$i-tcp" --mca btl tcp,self --mca osc pt2pt)"
  echo "SIGSTOP rank 3, UCX: $(stop_rank "$bin" "$work/s$i-ucx" --mca osc ucx)"
  echo "SIGTERM, one process: $(sigterm "$work/t$i-one" "$bin" render "$work/small.dcb" --width 64 --height 64 --frames 100000)"
  echo "SIGTERM to mpirun -n 4: $(sigterm "$work/t$i-mpi" mpirun --oversubscribe -n 4 "$bin" render "$work/small.dcb" --cache 1/8 --width 64 --height 64 --frames 100000)"
done
