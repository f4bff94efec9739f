#!/usr/bin/env python3
"""Median time per frame of this build against another build, on the full-rate KITTI clips.

Issue 21 measures speed as the median in-process time per frame against an older build, in
the same script. This shared 2-core host changes speed by up to 2x within an hour, so a
single pass (this build, then the other, clip by clip) favours whichever build ran in the
faster minutes. Here every round runs each clip with both builds, one run at a time, and
alternates which build goes first from round to round; the ratio is taken per pair of runs
(other / this: above 1 means this build is faster) and the table gives, per clip, the
median time per frame of each build over all rounds and the median of the pair ratios.

Each run is `supermvo run CLIP --mode inprocess` (the networks run unless
`SUPERMVO_NETWORK_CACHE` is set) with the same further arguments, and the time per frame is
`report.json`'s `timing_ms.frame_median` (features, matching and tracking; not the image
read). An older build is made from a worktree, for example:

    git worktree add ../old b96b65b && (cd ../old && cargo build --release -p supermvo --bin supermvo)
    python3 tools/speed_against_build.py ../old/target/release/supermvo [--rounds 6] [--json out.json] [-- ARGS]
"""
import argparse
import json
import os
import statistics
import sys
import tempfile

import clip_study


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("other", help="the other build's supermvo binary")
    ap.add_argument("--bin", default=os.path.join(clip_study.ROOT, "target", "release", "supermvo"))
    ap.add_argument("--clips", default=",".join(clip_study.CLIPS))
    ap.add_argument("--rounds", type=int, default=6, help="rounds; odd ones run the other build first")
    ap.add_argument("--json", help="also write every run's time here")
    ap.add_argument("extra", nargs="*", help="arguments passed on to every `supermvo run`")
    args = ap.parse_args()
    for b in (args.bin, args.other):
        if not os.access(b, os.X_OK):
            sys.exit(f"speed_against_build: {b} not found")
    clips = args.clips.split(",")
    runs = {c: [] for c in clips}
    with tempfile.TemporaryDirectory(prefix="speed_") as tmp:
        seqs = {c: clip_study.subsample(c, 1, tmp) for c in clips}
        for r in range(args.rounds):
            order = [("this", args.bin), ("other", args.other)]
            if r % 2:
                order.reverse()
            for c in clips:
                ms = {}
                for name, binary in order:
                    out = os.path.join(tmp, "out", f"{c}_{r}_{name}")
                    ms[name] = clip_study.run_one(binary, seqs[c], out, args.extra)["ms"]
                runs[c].append(dict(ms, first=order[0][0]))
                print(f"round {r + 1}, {c}: this {ms['this']:.1f} ms, other {ms['other']:.1f} ms, "
                      f"ratio {ms['other'] / ms['this']:.2f} ({order[0][0]} first)", flush=True)
    print(f"\n{'clip':<8} {'this ms':>8} {'other ms':>8} {'median ratio':>12}  ratio per round")
    every = []
    for c in clips:
        ratios = [p["other"] / p["this"] for p in runs[c]]
        every += ratios
        print(f"{c:<8} {statistics.median(p['this'] for p in runs[c]):8.1f} "
              f"{statistics.median(p['other'] for p in runs[c]):8.1f} {statistics.median(ratios):11.2f}x  "
              + " ".join(f"{x:.2f}" for x in ratios))
    print(f"all {len(every)} pairs: median ratio {statistics.median(every):.2f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"bin": args.bin, "other": args.other, "extra": args.extra, "runs": runs}, f, indent=1)


if __name__ == "__main__":
    main()
