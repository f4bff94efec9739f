#!/usr/bin/env python3
"""Scale drift of a long run: estimated over true distance on the first and the last stretch.

Issue 21's long-drive target: on a drive of 2 km or more, the scale of the last 200 m within
3 % of the scale of the first 200 m. For a run's `trajectory.kitti.txt` (frames without a
pose are absent or repeated, see `supermvo run`) and the KITTI ground truth, this prints the
ratio estimated / true distance over the first `--stretch` metres of true path (from the
first posed frame) and over the last (to the last posed frame), and their quotient. The
trajectory's frame `i` is line `i` of both files; the distances are summed frame to frame
over frames that have a pose, so gaps do not count.

    python3 tools/drive_scale.py RUN_DIR/trajectory.kitti.txt GT.txt [--report RUN_DIR/report.json]
"""
import argparse
import json
import math


def centres(path):
    out = []
    with open(path) as f:
        for line in f:
            v = [float(x) for x in line.split()]
            out.append((v[3], v[7], v[11]) if len(v) == 12 else None)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("estimate")
    ap.add_argument("ground_truth")
    ap.add_argument("--report", help="report.json of the run: only frames it says were posed count")
    ap.add_argument("--stretch", type=float, default=200.0)
    args = ap.parse_args()
    est, gt = centres(args.estimate), centres(args.ground_truth)
    n = min(len(est), len(gt))
    posed = [i for i in range(n) if est[i] is not None]
    if args.report:
        with open(args.report) as f:
            detail = json.load(f)["frames_detail"]
        ok = {d["index"] for d in detail if d.get("pose") is not None}
        # frames seen while initialising, posed later with the frame that initialised
        ok |= {late["index"] for d in detail for late in d.get("backfilled", [])}
        posed = [i for i in posed if i in ok]
    steps = list(zip(posed, posed[1:]))
    dist = math.dist

    def ratio(pairs):
        e = sum(dist(est[a], est[b]) for a, b in pairs)
        t = sum(dist(gt[a], gt[b]) for a, b in pairs)
        return e / t, t

    first, acc = [], 0.0
    for a, b in steps:
        if acc >= args.stretch:
            break
        first.append((a, b))
        acc += dist(gt[a], gt[b])
    last, acc = [], 0.0
    for a, b in reversed(steps):
        if acc >= args.stretch:
            break
        last.append((a, b))
        acc += dist(gt[a], gt[b])
    (s0, t0), (s1, t1) = ratio(first), ratio(last)
    total = sum(dist(gt[a], gt[b]) for a, b in steps)
    print(f"frames posed {len(posed)} of {n}, true path {total:.0f} m")
    print(f"scale first {t0:.0f} m {s0:.4f}, last {t1:.0f} m {s1:.4f}, last / first {s1 / s0:.4f} "
          f"({100 * (s1 / s0 - 1):+.1f} %)")


if __name__ == "__main__":
    main()
