#!/usr/bin/env python3
"""The validation table of `dcrt simulate`: for trace directories written by
scripts/simulate-validate.sh (OUT/<transport>-k<K>-r<run>/), each run's own-K prediction
against its measured mean frame interval, and predictions from the K=4 run of the same
batch and run number for K=5 and 6, as Markdown rows.

Usage: scripts/simulate-table.py DCRT OUT [OUT...] [-- extra simulate flags]
"""
import json
import statistics as st
import subprocess
import sys
from pathlib import Path


def main():
    args = sys.argv[1:]
    extra = []
    if "--" in args:
        i = args.index("--")
        args, extra = args[:i], args[i + 1:]
    if len(args) < 2:
        sys.exit(__doc__)
    dcrt, outs = args[0], [Path(a) for a in args[1:]]

    def sim(d, k):
        r = subprocess.run([dcrt, "simulate", str(d), "--ranks", str(k), "--tile", "32",
                            "--min-tile", "8", "--json", *extra], capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"{d}: {r.stderr.strip()}")
        return json.loads(r.stdout)

    print("| transport | K | runs | measured ms, median (range) | own-K: median prediction "
          "(median error, worst run) | from K = 4: median prediction (vs measured median; "
          "paired runs median, range) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for tr in ["shm", "tcp"]:
        own, from4 = {}, {}
        for out in outs:
            for d4 in sorted(out.glob(f"{tr}-k4-r*")):
                run = d4.name.split("-r")[-1]
                for k in [4, 5, 6]:
                    d = out / f"{tr}-k{k}-r{run}"
                    if not d.is_dir():
                        continue
                    p = sim(d, k)
                    own.setdefault(k, []).append((p["mean_frame_ms"],
                                                  p["measured_mean_frame_ms"]))
                    if k > 4:
                        from4.setdefault(k, []).append(
                            (sim(d4, k)["mean_frame_ms"], p["measured_mean_frame_ms"]))
        for k in sorted(own):
            ms = [m for _, m in own[k]]
            errs = [(p - m) / m * 100 for p, m in own[k]]
            mm = st.median(ms)
            row = (f"| {tr} | {k} | {len(ms)} | {mm:.0f} ({min(ms):.0f}-{max(ms):.0f}) | "
                   f"{st.median([p for p, _ in own[k]]):.0f} ({st.median(errs):+.1f}%, "
                   f"{max(errs, key=abs):+.1f}%) |")
            if k in from4:
                pm = st.median([p for p, _ in from4[k]])
                pe = [(p - m) / m * 100 for p, m in from4[k]]
                row += (f" {pm:.0f} ({(pm - mm) / mm * 100:+.1f}%; {st.median(pe):+.1f}%, "
                        f"{min(pe):+.0f}..{max(pe):+.0f}%) |")
            else:
                row += " |"
            print(row)


main()
