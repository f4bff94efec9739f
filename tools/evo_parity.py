#!/usr/bin/env python3
"""Compare `supermvo eval` with evo (https://github.com/MichaelGrupp/evo) statistic by statistic.

For every trajectory pair in ../shared/data/trajectories, every alignment (none, se3, sim3,
scale) and RPE steps of 1 frame, 1 m and 100 m, both tools compute APE (translation, rotation
angle in degrees, full transformation) and RPE (translation, rotation angle in degrees), and
every statistic (rmse mean median std min max sse) must agree to --rtol (default 1e-6).
Where evo finds no RPE pair for a step (100 m on a desk-sized scene), supermvo must report
the same.

Usage:
    pip install evo==1.38.1
    python3 tools/evo_parity.py [--bin target/release/supermvo] [--write-fixture FILE]

--write-fixture saves evo's numbers as JSON, which `tests/tests/evo_parity.rs` checks
against supermvo in CI without needing evo installed.
"""
import argparse
import copy
import json
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "trajectories"))

# (name, format, ground truth, estimate, t_max_diff)
PAIRS = [
    ("kitti00_orb", "kitti", "evo/KITTI_00_gt.txt", "evo/KITTI_00_ORB.txt", 0.01),
    ("kitti00_sptam", "kitti", "evo/KITTI_00_gt.txt", "evo/KITTI_00_SPTAM.txt", 0.01),
    ("fr1_xyz_rgbdslam", "tum", "evo/freiburg1_xyz-groundtruth.txt", "evo/freiburg1_xyz-rgbdslam.txt", 0.01),
    ("fr2_desk_orb", "tum", "evo/fr2_desk_groundtruth.txt", "evo/fr2_desk_ORB.txt", 0.01),
    ("paper00_supermvo", "tum", "supermvo-paper/00_gt_tum.txt", "supermvo-paper/00_supermvo_tum.txt", 0.02),
    ("paper00_orb", "tum", "supermvo-paper/00_gt_tum.txt", "supermvo-paper/00_orb_tum.txt", 0.02),
    ("euroc_v102", "euroc", "evo/V102_groundtruth.csv", "evo/V102.txt", 0.01),
]
ALIGNS = ["none", "se3", "sim3", "scale"]
DELTAS = [(1, "frames"), (1.0, "meters"), (100.0, "meters")]
STATS = ["rmse", "mean", "median", "std", "min", "max", "sse"]


def evo_numbers(fmt, gt, est, t_max_diff, align, delta, unit):
    """evo's statistics for one case, through its Python API (the code behind evo_ape/evo_rpe)."""
    from evo.core import metrics, sync
    from evo.core.filters import FilterException
    from evo.main_ape import ape
    from evo.main_rpe import rpe
    from evo.tools import file_interface

    if fmt == "kitti":
        ref = file_interface.read_kitti_poses_file(gt)
        est_t = file_interface.read_kitti_poses_file(est)
    else:
        ref = (file_interface.read_euroc_csv_trajectory(gt) if fmt == "euroc"
               else file_interface.read_tum_trajectory_file(gt))
        est_t = file_interface.read_tum_trajectory_file(est)
        ref, est_t = sync.associate_trajectories(ref, est_t, max_diff=t_max_diff)
    kw = dict(align=align in ("se3", "sim3"), correct_scale=align in ("sim3", "scale"))
    out = {"matched_poses": ref.num_poses, "ape": {}, "rpe": {}}
    for key, rel in [("trans", metrics.PoseRelation.translation_part),
                     ("rot_deg", metrics.PoseRelation.rotation_angle_deg),
                     ("full", metrics.PoseRelation.full_transformation)]:
        r = ape(copy.deepcopy(ref), copy.deepcopy(est_t), rel, **kw)
        out["ape"][key] = {k: float(r.stats[k]) for k in STATS}
    du = metrics.Unit.frames if unit == "frames" else metrics.Unit.meters
    for key, rel in [("trans", metrics.PoseRelation.translation_part),
                     ("rot_deg", metrics.PoseRelation.rotation_angle_deg)]:
        try:
            r = rpe(copy.deepcopy(ref), copy.deepcopy(est_t), rel, delta=delta, delta_unit=du, **kw)
            out["rpe"][key] = {k: float(r.stats[k]) for k in STATS}
        except FilterException:
            out["rpe"] = None
            break
    return out


def supermvo_numbers(binary, fmt, gt, est, t_max_diff, align, delta, unit):
    with tempfile.TemporaryDirectory() as d:
        js = os.path.join(d, "r.json")
        cmd = [binary, "eval", "--quiet", "--gt", gt, "--est", est, "--format", fmt,
               "--align", align, "--delta", str(delta), "--delta-unit", unit,
               "--t-max-diff", str(t_max_diff), "--json", js]
        subprocess.run(cmd, check=True)
        with open(js) as f:
            return json.load(f)


def close(a, b, rtol):
    return abs(a - b) <= rtol * max(abs(a), abs(b)) or abs(a - b) <= 1e-12


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--rtol", type=float, default=1e-6)
    ap.add_argument("--write-fixture", help="write evo's numbers to this JSON file")
    args = ap.parse_args()
    if not os.path.isdir(DATA):
        sys.exit(f"evo_parity: {DATA} not found; it holds the test trajectories")
    try:
        import evo  # noqa: F401
    except ImportError:
        sys.exit("evo_parity: evo is not installed; run: python3 -m pip install evo==1.38.1")
    if not os.path.exists(args.bin):
        subprocess.run(["cargo", "build", "--release", "-p", "supermvo"], cwd=ROOT, check=True)

    import evo
    fixture = {"evo_version": evo.__version__, "cases": []}
    checked = failed = 0
    worst = 0.0
    print(f"evo {evo.__version__} vs supermvo, rtol {args.rtol}")
    print(f"{'case':<18} {'align':<6} {'rpe delta':<10} {'poses':>6} {'APE rmse (m)':>14} {'RPE rmse (m)':>14} {'max rel diff':>13}  result")
    for name, fmt, gt_rel, est_rel, tmd in PAIRS:
        gt, est = os.path.join(DATA, gt_rel), os.path.join(DATA, est_rel)
        for align in ALIGNS:
            for delta, unit in DELTAS:
                ref = evo_numbers(fmt, gt, est, tmd, align, delta, unit)
                ours = supermvo_numbers(args.bin, fmt, gt, est, tmd, align, delta, unit)
                fixture["cases"].append({"name": name, "format": fmt, "gt": gt_rel, "est": est_rel,
                                         "t_max_diff": tmd, "align": align, "delta": delta,
                                         "delta_unit": unit, "evo": ref})
                bad = []
                case_worst = 0.0
                if ours["matched_poses"] != ref["matched_poses"]:
                    bad.append(f"matched poses {ours['matched_poses']} vs {ref['matched_poses']}")
                for metric in ("ape", "rpe"):
                    if ref[metric] is None or ours[metric] is None:
                        if (ref[metric] is None) != (ours[metric] is None):
                            bad.append(f"{metric}: evo {'none' if ref[metric] is None else 'some'}, supermvo {'none' if ours[metric] is None else 'some'}")
                        continue
                    for rel, stats in ref[metric].items():
                        for k, v in stats.items():
                            w = ours[metric][rel][k]
                            checked += 1
                            d = abs(v - w) / max(abs(v), 1e-300)
                            case_worst = max(case_worst, d if abs(v - w) > 1e-12 else 0.0)
                            if not close(v, w, args.rtol):
                                bad.append(f"{metric}.{rel}.{k}: evo {v!r} supermvo {w!r}")
                worst = max(worst, case_worst)
                rpe_rmse = f"{ref['rpe']['trans']['rmse']:.6f}" if ref["rpe"] else "no pairs"
                print(f"{name:<18} {align:<6} {str(delta) + ' ' + unit[0]:<10} {ref['matched_poses']:>6} "
                      f"{ref['ape']['trans']['rmse']:>14.6f} {rpe_rmse:>14} {case_worst:>13.2e}  {'ok' if not bad else 'FAIL'}")
                for b in bad:
                    failed += 1
                    print("    " + b)
    print(f"{checked} statistics compared, {failed} differ beyond rtol {args.rtol}; largest relative difference {worst:.2e}")
    if args.write_fixture:
        with open(args.write_fixture, "w") as f:
            json.dump(fixture, f, indent=1)
            f.write("\n")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
