#!/usr/bin/env python3
"""Compare `supermvo graph optimize` with GTSAM 4.3 on every graph in ../shared/data/posegraph.

GTSAM is set up as ../shared/data/README.md describes: readG2o, a prior on vertex 0 with
variances (1e-6 rad^2 x3, 1e-4 m^2 x3) for 3D graphs and (1e-4, 1e-4, 1e-6) for 2D graphs,
default LevenbergMarquardtParams. Reported: initial and final error of both (must agree to
--rtol, default 0.1 %), iterations, and optimisation time (median of --runs; reading the
file is not timed for either). For ring and ringCity, the ATE (RMSE of positions after
SE(2) alignment) of both optimised graphs against the _groundtruth graphs.

    python3 -m pip install gtsam==4.3.0
    python3 tools/gtsam_parity.py [--runs 5] [--bin target/release/supermvo]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "posegraph"))
GRAPHS = ["sphere2500", "intel", "manhattanOlson3500", "city10000", "ring", "ringCity"]


def gtsam_run(path, is3d):
    import gtsam
    graph, initial = gtsam.readG2o(path, is3d)
    if is3d:
        noise = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
        graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), noise))
    else:
        noise = gtsam.noiseModel.Diagonal.Variances(np.array([1e-4, 1e-4, 1e-6]))
        graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), noise))
    params = gtsam.LevenbergMarquardtParams()
    t = time.perf_counter()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    result = opt.optimize()
    seconds = time.perf_counter() - t
    return {"initial_error": graph.error(initial), "final_error": graph.error(result),
            "iterations": opt.iterations(), "seconds": seconds, "result": result}


def positions2d(values_or_path):
    import gtsam
    if isinstance(values_or_path, str):
        _, values_or_path = gtsam.readG2o(values_or_path, False)
    keys = sorted(values_or_path.keys())
    return np.array([[values_or_path.atPose2(k).x(), values_or_path.atPose2(k).y()] for k in keys])


def ate(est, ref):
    """RMSE after rigid (rotation + translation) alignment, Umeyama in 2D."""
    mu_e, mu_r = est.mean(0), ref.mean(0)
    cov = (ref - mu_r).T @ (est - mu_e) / len(est)
    u, _, vt = np.linalg.svd(cov)
    s = np.eye(2)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[1, 1] = -1
    r = u @ s @ vt
    aligned = (r @ (est - mu_e).T).T + mu_r
    return float(np.sqrt(((aligned - ref) ** 2).sum(1).mean()))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--rtol", type=float, default=1e-3)
    ap.add_argument("--write-fixture", help="save GTSAM's numbers as JSON (for the Rust parity test)")
    args = ap.parse_args()
    try:
        import gtsam  # noqa: F401
    except ImportError:
        sys.exit("gtsam_parity: gtsam is not installed; run: python3 -m pip install gtsam==4.3.0")
    if not os.path.isdir(DATA):
        sys.exit(f"gtsam_parity: {DATA} not found")
    failed = 0
    fixture = {"gtsam_version": "4.3.0", "graphs": {}}
    print(f"{'graph':<20} {'initial (GTSAM)':>16} {'initial (ours)':>16} {'final (GTSAM)':>14} {'final (ours)':>14} "
          f"{'it G/o':>7} {'GTSAM s':>8} {'ours s':>8} {'speed-up':>8}  result")
    for name in GRAPHS:
        path = os.path.join(DATA, name + ".g2o")
        with open(path) as f:
            is3d = "SE3" in f.readline()
        g_times, o_times = [], []
        with tempfile.TemporaryDirectory() as d:
            js, out = os.path.join(d, "r.json"), os.path.join(d, "out.g2o")
            for _ in range(args.runs):
                g = gtsam_run(path, is3d)
                g_times.append(g["seconds"])
                subprocess.run([args.bin, "graph", "optimize", path, "--json", js, "--out", out], check=True,
                               capture_output=True)
                with open(js) as f:
                    o = json.load(f)
                o_times.append(o["seconds"])
            ok = all(abs(g[k] - o[k]) <= args.rtol * abs(g[k]) for k in ("initial_error", "final_error"))
            failed += not ok
            gs, os_ = statistics.median(g_times), statistics.median(o_times)
            print(f"{name:<20} {g['initial_error']:>16.6f} {o['initial_error']:>16.6f} {g['final_error']:>14.6f} "
                  f"{o['final_error']:>14.6f} {g['iterations']:>3}/{o['iterations']:<3} {gs:>8.3f} {os_:>8.3f} "
                  f"{gs / os_:>7.1f}x  {'ok' if ok else 'DIFFERENT'}")
            fixture["graphs"][name] = {k: g[k] for k in ("initial_error", "final_error", "iterations")}
            gt = os.path.join(DATA, name + "_groundtruth.g2o")
            if os.path.exists(gt) and not is3d:
                ref = positions2d(gt)
                ates = (ate(positions2d(g['result']), ref), ate(positions2d(out), ref), ate(positions2d(path), ref))
                fixture["graphs"][name]["ate_vs_groundtruth"] = ates[0]
                print(f"    ATE vs {name}_groundtruth: GTSAM {ates[0]:.6f} m, ours {ates[1]:.6f} m, initial {ates[2]:.6f} m")
    if args.write_fixture:
        with open(args.write_fixture, "w") as f:
            json.dump(fixture, f, indent=1)
            f.write("\n")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
