#!/usr/bin/env python3
"""How much each KITTI clip's accuracy depends on the tracker's RANSAC seed.

Runs `supermvo run SEQ --mode inprocess --seed S` on every clip in ../shared/data/kitti for
seeds 0..N-1 (0 is the seed of the accuracy table in docs/results.md), reads each run's APE RMSE
after Sim(3) alignment from its report.json, and prints per clip every seed's APE, the
median, and how many seeds meet issue 4's target. Any further arguments go to every
`supermvo run` (for example `--frontend orb` or `--ba-window 10`), so a change to the
tracker can be judged on the distribution over seeds rather than on one run per clip.

    python3 tools/seed_study.py --seeds 8 [-- --ba-window 10]

Each run takes 10-60 s on a 2-core machine (five clips, 51-300 frames).
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences"))
TARGETS = {"00": 0.5, "01": 0.5, "03": 1.0, "06": 0.5, "07": 0.5}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=8, help="seeds 0..N-1 (default 8)")
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("extra", nargs="*", help="arguments passed on to every `supermvo run`")
    args = ap.parse_args()
    if not os.path.isdir(SHARED):
        sys.exit(f"seed_study: {SHARED} not found (the KITTI clips of ../shared/data)")
    if not os.access(args.bin, os.X_OK):
        sys.exit(f"seed_study: {args.bin} not found; run `cargo build --release --workspace --bins` first")
    clips = [c for c in sorted(TARGETS) if os.path.isdir(os.path.join(SHARED, c))]
    ape = {c: [] for c in clips}
    with tempfile.TemporaryDirectory() as out:
        for seed in range(args.seeds):
            for c in clips:
                d = os.path.join(out, f"{c}_{seed}")
                cmd = [args.bin, "run", os.path.join(SHARED, c), "--mode", "inprocess", "--quiet",
                       "--seed", str(seed), "--out", d] + args.extra
                r = subprocess.run(cmd, capture_output=True, text=True)
                if r.returncode != 0:
                    sys.exit(f"seed_study: `{' '.join(cmd)}` failed:\n{r.stderr[-2000:]}")
                with open(os.path.join(d, "report.json")) as f:
                    ape[c].append(json.load(f)["eval"]["ape"]["trans"]["rmse"])
            print(f"seed {seed}: " + " ".join(f"{c}={ape[c][-1]:.3f}" for c in clips), flush=True)
    print(f"\nAPE RMSE (m) after Sim(3) alignment, seeds 0-{args.seeds - 1}"
          + (f", extra arguments: {' '.join(args.extra)}" if args.extra else ""))
    print(f"{'clip':<5} {'target':>6} {'median':>7} {'min':>6} {'max':>6} {'seeds meeting':>13}  per seed")
    for c in clips:
        v = ape[c]
        ok = sum(x <= TARGETS[c] for x in v)
        print(f"{c:<5} {TARGETS[c]:>6.1f} {statistics.median(v):>7.3f} {min(v):>6.3f} {max(v):>6.3f} "
              f"{f'{ok} of {len(v)}':>13}  " + " ".join(f"{x:.3f}" for x in v))


if __name__ == "__main__":
    main()
