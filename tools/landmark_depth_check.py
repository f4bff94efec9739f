#!/usr/bin/env python3
"""How right are a run's new landmarks? Each one's depth against the ground truth's.

The tracker logs every landmark it creates (trace target `supermvo::landmarks`): its source
(`matcher`: the network's matches between keyframes; `covisible`: epipolar pairing), the
frames of its first and last observation with their normalised image coordinates, how many
keyframes observe it, and its depth in the last view over the distance between the two
camera centres. This tool triangulates the same two observations with the ground-truth poses
of those frames and compares the two depth-over-baseline numbers. Being scale-free, the ratio
is 1 for a right landmark whatever the map's scale; a pair matched to the wrong keypoint
along the epipolar line, or a biased triangulation, moves it.

    SUPERMVO_LOG=supermvo::landmarks=trace supermvo run SEQ --mode inprocess -q 2> run.log
    python3 tools/landmark_depth_check.py run.log GT.txt [--bins 100]

It prints, per source and number of observations: how many landmarks, the median of the log
depth ratio (its sign: placed too far or too close), its median absolute deviation, and the
share off by more than 20 %; with `--bins N`, the same per N frames (by the frame of the last
observation). `--self-test` checks the computation on constructed landmarks and exits.
"""
import argparse
import math
import os
import re
import statistics
import sys
import tempfile

FIELD = re.compile(r'(\w+)=("[^"]*"|\S+)')


def read_poses(path):
    """KITTI poses: a list of (R rows, centre) per line, `T_world_cam`."""
    poses = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            v = line.split()
            if not v:
                continue
            if len(v) != 12:
                sys.exit(f"landmark_depth_check: {path}:{n}: {len(v)} numbers, a KITTI pose has 12")
            x = [float(a) for a in v]
            poses.append(([x[0:3], x[4:7], x[8:11]], [x[3], x[7], x[11]]))
    return poses


def read_landmarks(path):
    """The `new landmark` events of a run's log, as dicts."""
    out = []
    with open(path, errors="replace") as f:
        for line in f:
            if "new landmark" not in line:
                continue
            d = {k: v.strip('"') for k, v in FIELD.findall(line)}
            try:
                out.append({
                    "source": d["source"],
                    "first": int(d["first_frame"]),
                    "last": int(d["last_frame"]),
                    "obs": int(d["observations"]),
                    "b0": (float(d["first_x"]), float(d["first_y"]), 1.0),
                    "b1": (float(d["last_x"]), float(d["last_y"]), 1.0),
                    "ratio": float(d["depth_over_baseline"]),
                })
            except (KeyError, ValueError):
                continue
    return out


def rotate(r, b):
    return [sum(r[i][k] * b[k] for k in range(3)) for i in range(3)]


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def sub(a, b):
    return [x - y for x, y in zip(a, b)]


def true_ratio(pose0, pose1, b0, b1):
    """Depth in camera 1 over the baseline, of the point closest to both rays under the
    ground truth; None when the rays are parallel or it lies behind a camera."""
    (r0, c0), (r1, c1) = pose0, pose1
    d0, d1 = rotate(r0, b0), rotate(r1, b1)
    w = sub(c0, c1)
    a, b, c = dot(d0, d0), dot(d0, d1), dot(d1, d1)
    d, e = dot(d0, w), dot(d1, w)
    den = a * c - b * b
    baseline = math.sqrt(dot(w, w))
    if abs(den) < 1e-15 or baseline < 1e-9:
        return None
    s, t = (b * e - c * d) / den, (a * e - b * d) / den
    if s <= 0 or t <= 0:
        return None
    p = [0.5 * (c0[i] + s * d0[i] + c1[i] + t * d1[i]) for i in range(3)]
    # depth in camera 1: the third row of R^T (p - c1)
    q = sub(p, c1)
    depth = sum(r1[k][2] * q[k] for k in range(3))
    return depth / baseline


def log_ratios(landmarks, poses):
    """(landmark, log of estimated over true depth-over-baseline) for each that can be
    compared."""
    out = []
    for lm in landmarks:
        if max(lm["first"], lm["last"]) >= len(poses) or lm["ratio"] <= 0:
            continue
        t = true_ratio(poses[lm["first"]], poses[lm["last"]], lm["b0"], lm["b1"])
        if t is not None and t > 0:
            out.append((lm, math.log(lm["ratio"] / t)))
    return out


def summary(values):
    med = statistics.median(values)
    mad = statistics.median(abs(v - med) for v in values)
    off = sum(1 for v in values if abs(v) > math.log(1.2)) / len(values)
    return f"{len(values):6d}  {med:+.4f}  {mad:.4f}  {100 * off:5.1f} %"


def report(pairs, bins):
    print("source     observations  landmarks  median log ratio  MAD  off by > 20 %")
    groups = {}
    for lm, v in pairs:
        key = (lm["source"], min(lm["obs"], 4))
        groups.setdefault(key, []).append(v)
        groups.setdefault((lm["source"], 0), []).append(v)
    for (source, n), values in sorted(groups.items()):
        label = "all" if n == 0 else ("4+" if n == 4 else str(n))
        print(f"{source:10s} {label:>12s}  {summary(values)}")
    if bins:
        print(f"\nper {bins} frames (frame of the last observation): source, landmarks, median, MAD, off")
        by_bin = {}
        for lm, v in pairs:
            by_bin.setdefault((lm["last"] // bins, lm["source"]), []).append(v)
        for b in sorted({k[0] for k in by_bin}):
            cells = [f"{s} {summary(by_bin[(b, s)])}" for s in ("matcher", "covisible") if (b, s) in by_bin]
            print(f"{b * bins:6d}  " + "  |  ".join(cells))


def self_test():
    """Landmarks built from known geometry: right ones give ratio 1, one at 0.8 of its
    depth gives log(0.8)."""
    ident = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    poses = [(ident, [0.0, 0.0, float(z)]) for z in range(4)]
    points = [[3.0, -1.0, 20.0], [-4.0, 0.5, 12.0], [1.0, 2.0, 30.0]]
    lms = []
    for p in points:
        b0 = (p[0] / p[2], p[1] / p[2], 1.0)
        q = [p[0], p[1], p[2] - 3.0]
        b1 = (q[0] / q[2], q[1] / q[2], 1.0)
        lms.append({"source": "matcher", "first": 0, "last": 3, "obs": 2, "b0": b0, "b1": b1,
                    "ratio": q[2] / 3.0})
    wrong = dict(lms[0], ratio=lms[0]["ratio"] * 0.8)
    pairs = log_ratios(lms + [wrong], poses)
    assert len(pairs) == 4, pairs
    for _, v in pairs[:3]:
        assert abs(v) < 1e-9, v
    assert abs(pairs[3][1] - math.log(0.8)) < 1e-9, pairs[3]
    line = 'TRACE supermvo::landmarks: new landmark source="covisible" first_frame=0 last_frame=3 ' \
           'observations=2 first_x=0.15 first_y=-0.05 last_x=0.1764705882352941 ' \
           'last_y=-0.058823529411764705 depth_over_baseline=5.666666666666667'
    with tempfile.NamedTemporaryFile("w", suffix=".log", delete=False) as f:
        f.write("unrelated line\n" + line + "\n")
    try:
        parsed = read_landmarks(f.name)
    finally:
        os.unlink(f.name)
    assert len(parsed) == 1 and parsed[0]["source"] == "covisible", parsed
    assert abs(log_ratios(parsed, poses)[0][1]) < 1e-9
    print("landmark_depth_check: self-test passed")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", nargs="?", help="stderr of a run with SUPERMVO_LOG=supermvo::landmarks=trace")
    ap.add_argument("ground_truth", nargs="?", help="KITTI poses of the sequence")
    ap.add_argument("--bins", type=int, default=0, help="also per this many frames")
    ap.add_argument("--self-test", action="store_true")
    args = ap.parse_args()
    if args.self_test:
        self_test()
        return
    if not (args.log and args.ground_truth):
        ap.error("give the run's log and the ground truth (or --self-test)")
    try:
        landmarks = read_landmarks(args.log)
        poses = read_poses(args.ground_truth)
    except OSError as e:
        sys.exit(f"landmark_depth_check: {e.filename}: {e.strerror}")
    if not landmarks:
        sys.exit(f"landmark_depth_check: {args.log}: no 'new landmark' events; run with "
                 "SUPERMVO_LOG=supermvo::landmarks=trace and keep stderr")
    pairs = log_ratios(landmarks, poses)
    if not pairs:
        sys.exit(f"landmark_depth_check: none of the {len(landmarks)} landmarks could be compared "
                 f"with {args.ground_truth} (frames beyond it?)")
    report(pairs, args.bins)


if __name__ == "__main__":
    main()
