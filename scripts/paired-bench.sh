#!/usr/bin/env bash
# Two dcrt builds measured side by side: on a loaded or noisy machine single runs swing by more
# than most changes, so both run `dcrt bench rays` at the same time, each on a core of its own with
# one llvmpipe thread, the cores swapped every pair. Prints per pair and row the median and
# minimum trace ms of each and their ratios (B / A: below 1 means B is faster).
#
#   scripts/paired-bench.sh DCRT_A DCRT_B PAIRS [dcrt bench rays options...]
#   e.g. scripts/paired-bench.sh /tmp/dcrt-before target/release/dcrt 4 --generator rm --runs 5
#
# Needs two free cores (CORES="0 1" by default), taskset and python3.
set -euo pipefail
[ $# -ge 3 ] || { sed -n '2,10p' "$0" >&2; exit 2; }
a="$1" b="$2" pairs="$3"
shift 3
for bin in "$a" "$b"; do
    [ -x "$bin" ] || { echo "paired-bench: $bin is not an executable" >&2; exit 1; }
done
read -r c0 c1 <<<"${CORES:-0 1}"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
for i in $(seq 1 "$pairs"); do
    if [ $((i % 2)) = 1 ]; then ca=$c0 cb=$c1; else ca=$c1 cb=$c0; fi
    LP_NUM_THREADS=1 taskset -c "$ca" "$a" bench rays --json -q "$@" >"$tmp/a.json" 2>"$tmp/a.err" &
    pa=$!
    LP_NUM_THREADS=1 taskset -c "$cb" "$b" bench rays --json -q "$@" >"$tmp/b.json" 2>"$tmp/b.err" &
    pb=$!
    wait "$pa" || { cat "$tmp/a.err" >&2; exit 1; }
    wait "$pb" || { cat "$tmp/b.err" >&2; exit 1; }
    python3 - "$tmp/a.json" "$tmp/b.json" "$i" <<'PY'
import json, sys
a, b = (json.load(open(p))["rows"] for p in sys.argv[1:3])
for ra, rb in zip(a, b):
    key = "%s %s %s" % (ra["preset"], ra["store"], ra["mode"])
    med = rb["trace_ms_median"] / ra["trace_ms_median"]
    low = rb["trace_ms_min"] / ra["trace_ms_min"]
    print("pair %s %-24s A med %8.1f min %8.1f | B med %8.1f min %8.1f | B/A med %.3f min %.3f"
          % (sys.argv[3], key, ra["trace_ms_median"], ra["trace_ms_min"],
             rb["trace_ms_median"], rb["trace_ms_min"], med, low))
PY
done
