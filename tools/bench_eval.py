#!/usr/bin/env python3
"""Benchmark: trajectory evaluation speed of supermvo against evo, in one run.

Work: KITTI 00 ground truth (4541 poses) vs ORB-SLAM2's estimate, SE(3) alignment,
APE (translation, rotation angle, full), RPE (translation, rotation angle; 1 frame and
100 m), and for supermvo also the KITTI metric (evo has none).

* supermvo: the release binary as a subprocess, so process start, file parsing and JSON
  output are all counted.
* evo: its Python API in this process (imports done once beforehand, not counted), file
  reading counted.

Both alternate for --runs rounds; the script prints medians and the ratio. The machine is
shared, so only the ratio is meaningful, and only within one run of this script.
"""
import argparse
import copy
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "trajectories", "evo"))


def run_evo(gt, est):
    from evo.core import metrics
    from evo.main_ape import ape
    from evo.main_rpe import rpe
    from evo.tools import file_interface
    ref = file_interface.read_kitti_poses_file(gt)
    e = file_interface.read_kitti_poses_file(est)
    for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg,
                metrics.PoseRelation.full_transformation):
        ape(copy.deepcopy(ref), copy.deepcopy(e), rel, align=True)
    for delta, unit in ((1, metrics.Unit.frames), (100.0, metrics.Unit.meters)):
        for rel in (metrics.PoseRelation.translation_part, metrics.PoseRelation.rotation_angle_deg):
            rpe(copy.deepcopy(ref), copy.deepcopy(e), rel, delta=delta, delta_unit=unit, align=True)


def run_supermvo(binary, gt, est, out):
    for delta, unit in (("1", "frames"), ("100", "meters")):
        subprocess.run([binary, "eval", "-q", "--gt", gt, "--est", est, "--align", "se3", "--delta", delta,
                        "--delta-unit", unit, "--json", out], check=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args()
    gt, est = os.path.join(DATA, "KITTI_00_gt.txt"), os.path.join(DATA, "KITTI_00_ORB.txt")
    if not os.path.exists(gt):
        sys.exit(f"bench_eval: {gt} not found")
    try:
        import evo
        from evo.main_ape import ape  # noqa: F401  (import cost not counted)
        from evo.main_rpe import rpe  # noqa: F401
    except ImportError:
        sys.exit("bench_eval: evo is not installed; run: python3 -m pip install evo==1.38.1")
    if not os.path.exists(args.bin):
        subprocess.run(["cargo", "build", "--release", "-p", "supermvo"], cwd=ROOT, check=True)
    ours, theirs = [], []
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "r.json")
        run_supermvo(args.bin, gt, est, out)  # warm the page cache
        for _ in range(args.runs):
            t = time.perf_counter(); run_supermvo(args.bin, gt, est, out); ours.append(time.perf_counter() - t)
            t = time.perf_counter(); run_evo(gt, est); theirs.append(time.perf_counter() - t)
    mo, me = statistics.median(ours), statistics.median(theirs)
    print(f"KITTI 00, 4541 poses, {args.runs} runs each, alternating; evo {evo.__version__}; {os.cpu_count()} CPUs")
    print(f"supermvo eval (APE+RPE+KITTI metric, 2 processes): median {mo * 1e3:8.1f} ms  (min {min(ours) * 1e3:.1f}, max {max(ours) * 1e3:.1f})")
    print(f"evo Python API (APE+RPE, in-process):              median {me * 1e3:8.1f} ms  (min {min(theirs) * 1e3:.1f}, max {max(theirs) * 1e3:.1f})")
    print(f"speed-up (evo median / supermvo median): {me / mo:.1f}x")


if __name__ == "__main__":
    main()
