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
                                 [--per-frames N]

`--per-frames N` prints the same ratio for every N frames instead (where along the road the
scale changes: on KITTI 00_long it steps at the turns' exits), with the ground truth's
heading change over those frames, the angle by which the estimate's rotation over them
differs from the truth's (where the estimate turns when the camera does not, or turns too
little) and, with `--report`, how many of them became keyframes. Both forms end with the
rotation error over the whole run (first to last posed frame). `--self-test` checks them on
constructed trajectories and exits.
"""
import argparse
import json
import math
import sys


def read_poses(path):
    """Each line's 12 numbers (a KITTI 3x4 `T_world_cam`), or None where a line has not 12."""
    with open(path) as f:
        rows = [[float(x) for x in line.split()] for line in f]
    return [v if len(v) == 12 else None for v in rows]


def centre(v):
    return None if v is None else (v[3], v[7], v[11])


def heading(v):
    """Degrees of rotation about the camera's y axis."""
    return None if v is None else math.degrees(math.atan2(v[2], v[10]))


def rotation(v):
    """The 3x3 rotation of a 3x4 row-major pose, as rows."""
    return None if v is None else [v[0:3], v[4:7], v[8:11]]


def rotation_error(est, gt, a, b):
    """Degrees between the estimate's rotation from frame `a` to `b` and the truth's: the
    angle of (Rg_a^T Rg_b)^T (Re_a^T Re_b)."""
    def mul_t(p, q):  # p^T q
        return [[sum(p[k][i] * q[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    e, g = mul_t(est[a], est[b]), mul_t(gt[a], gt[b])
    d = mul_t(g, e)
    c = (d[0][0] + d[1][1] + d[2][2] - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def posed_frames(est, n, report):
    """The frames with a pose, only those `report` (report.json's `frames_detail`) posed."""
    posed = [i for i in range(n) if est[i] is not None]
    if report is None:
        return posed
    ok = {d["index"] for d in report if d.get("pose") is not None}
    # frames seen while initialising, posed later with the frame that initialised
    ok |= {late["index"] for d in report for late in d.get("backfilled", [])}
    return [i for i in posed if i in ok]


def ratio(est, gt, pairs):
    """Estimated over true distance summed over `pairs` of frames, and the true distance."""
    e = sum(math.dist(est[a], est[b]) for a, b in pairs)
    t = sum(math.dist(gt[a], gt[b]) for a, b in pairs)
    return (e / t if t > 0 else float("nan")), t


def first_and_last(est, gt, steps, stretch):
    """The ratio over the first and over the last `stretch` metres of true path."""
    def take(seq):
        out, acc = [], 0.0
        for a, b in seq:
            if acc >= stretch:
                break
            out.append((a, b))
            acc += math.dist(gt[a], gt[b])
        return out
    return ratio(est, gt, take(steps)), ratio(est, gt, take(reversed(steps)))


def per_frames(est, gt, heading, rotations, steps, n, keyframes=None):
    """(first frame, ratio, heading change in degrees, keyframes or None, rotation error in
    degrees) per `n` frames; `rotations`: the (estimated, true) rotations per frame."""
    windows = {}
    for a, b in steps:
        # a step counts in the window it starts in, when it also ends there
        if b <= (a // n + 1) * n:
            windows.setdefault(a // n * n, []).append((a, b))
    out = []
    last = steps[-1][1] if steps else 0
    for start, pairs in sorted(windows.items()):
        s, _ = ratio(est, gt, pairs)
        end = min(start + n, last)
        turn = (heading[end] - heading[start] + 180.0) % 360.0 - 180.0
        kf = None if keyframes is None else sum(1 for k in keyframes if start <= k < start + n)
        rot = rotation_error(*rotations, pairs[0][0], pairs[-1][1])
        out.append((start, s, turn, kf, rot))
    return out


def self_test():
    # a straight drive at 1 m a frame, estimated at scale 0.5 for 20 frames, then 0.6
    gt = [(0.0, 0.0, float(i)) for i in range(41)]
    est, z = [], 0.0
    for i in range(41):
        est.append((0.0, 0.0, z))
        z += 0.5 if i < 20 else 0.6
    steps = list(zip(range(41), range(1, 41)))
    (s0, t0), (s1, t1) = first_and_last(est, gt, steps, 10.0)
    assert abs(s0 - 0.5) < 1e-12 and abs(s1 - 0.6) < 1e-12 and t0 == t1 == 10.0, (s0, s1, t0, t1)
    # the estimate turning 0.1 degree a frame about the vertical where the truth goes straight
    def yawed(deg):
        c, s_ = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        return [[c, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c]]
    rotations = ([yawed(0.1 * i) for i in range(41)], [yawed(0.0)] * 41)
    rows = per_frames(est, gt, [0.0] * 41, rotations, steps, 10, keyframes=[0, 3, 12, 35])
    assert [round(r[1], 12) for r in rows] == [0.5, 0.5, 0.6, 0.6], rows
    assert [r[3] for r in rows] == [2, 1, 0, 1], rows
    # a quarter turn to the left over frames 10-20: the heading change of that window
    heading = [0.0] * 10 + [9.0 * k for k in range(11)] + [90.0] * 20
    assert abs(per_frames(est, gt, heading, rotations, steps, 10)[1][2] - 90.0) < 1e-12
    # the estimate's turn of 1 degree per 10 frames, and of 4 over the whole drive
    assert all(abs(r[4] - 1.0) < 1e-9 for r in rows), rows
    assert abs(rotation_error(*rotations, 0, 40) - 4.0) < 1e-9
    # a frame without a pose drops its two steps, and the report can drop more
    est[5] = None
    assert posed_frames(est, 41, None) == [i for i in range(41) if i != 5]
    report = [{"index": i, "pose": [0] * 12 if i != 7 else None, "backfilled": []} for i in range(41)]
    assert 7 not in posed_frames(est, 41, report)
    print("drive_scale: self-test passed")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("estimate", nargs="?")
    ap.add_argument("ground_truth", nargs="?")
    ap.add_argument("--report", help="report.json of the run: only frames it says were posed count")
    ap.add_argument("--stretch", type=float, default=200.0)
    ap.add_argument("--per-frames", type=int, metavar="N", help="the ratio per N frames instead")
    ap.add_argument("--self-test", action="store_true")
    args = ap.parse_args()
    if args.self_test:
        return self_test()
    if not (args.estimate and args.ground_truth):
        ap.error("an estimate and a ground truth are needed (or --self-test)")
    if args.per_frames is not None and args.per_frames < 1:
        ap.error(f"--per-frames {args.per_frames}: give a number of frames of at least 1")
    try:
        est_poses = read_poses(args.estimate)
        est = [centre(v) for v in est_poses]
        gt_poses = read_poses(args.ground_truth)
        gt = [centre(v) for v in gt_poses]
        detail = None
        if args.report:
            with open(args.report) as f:
                detail = json.load(f)["frames_detail"]
    except (OSError, ValueError, KeyError) as e:
        sys.exit(f"drive_scale: cannot read the inputs ({e}); give a KITTI trajectory, its "
                 "ground truth and the run's report.json")
    n = min(len(est), len(gt))
    posed = posed_frames(est, n, detail)
    steps = list(zip(posed, posed[1:]))
    total = sum(math.dist(gt[a], gt[b]) for a, b in steps)
    print(f"frames posed {len(posed)} of {n}, true path {total:.0f} m")
    rotations = ([rotation(v) for v in est_poses], [rotation(v) for v in gt_poses])
    if args.per_frames:
        keyframes = None if detail is None else [d["index"] for d in detail if d.get("keyframe")]
        headings = [heading(v) for v in gt_poses]
        print("frames      est / true   heading change (deg)   rotation error (deg)"
              + ("   keyframes" if keyframes is not None else ""))
        rows = per_frames(est, gt, headings, rotations, steps, args.per_frames, keyframes)
        for start, s, turn, kf, rot in rows:
            line = f"{start:5d}-{start + args.per_frames - 1:<5d} {s:10.4f}   {turn:+8.1f}" \
                f"               {rot:8.2f}"
            print(line + (f"   {kf:9d}" if kf is not None else ""))
    else:
        (s0, t0), (s1, t1) = first_and_last(est, gt, steps, args.stretch)
        print(f"scale first {t0:.0f} m {s0:.4f}, last {t1:.0f} m {s1:.4f}, last / first "
              f"{s1 / s0:.4f} ({100 * (s1 / s0 - 1):+.1f} %)")
    if steps:
        first, last = steps[0][0], steps[-1][1]
        print(f"rotation error over the run (frames {first}-{last}): "
              f"{rotation_error(*rotations, first, last):.2f} deg")


if __name__ == "__main__":
    main()
