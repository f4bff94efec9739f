#!/usr/bin/env python3
"""Write OpenCV's answers to seeded synthetic problems (KITTI 00 intrinsics, Gaussian pixel
noise sigma 0.5) as fixtures for shared/geometry/tests/:
* tests/fixtures/opencv_essential.json: findEssentialMat + recoverPose, 300 points, 20 % outliers;
* tests/fixtures/opencv_pnp.json: solvePnPRansac (SOLVEPNP_ITERATIVE), 200 points, 25 % outliers.

    python3 -m pip install opencv-python-headless numpy
    python3 tools/make_geometry_fixtures.py
"""
import json
import os

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
K = np.array([[718.856, 0, 607.1928], [0, 718.856, 185.2157], [0, 0, 1]])


def rot(w):
    r, _ = cv2.Rodrigues(np.asarray(w, float))
    return r


def case(seed):
    rng = np.random.default_rng(seed)
    r = rot([rng.normal(0, 0.01), rng.uniform(-0.3, 0.3), rng.normal(0, 0.01)])
    t = np.array([rng.uniform(-0.3, 0.3), rng.normal(0, 0.02), -1.0])
    t /= np.linalg.norm(t)
    p1, p2 = [], []
    while len(p1) < 300:
        x = np.array([rng.uniform(-15, 15), rng.uniform(-3, 2), rng.uniform(4, 40)])
        y = r @ x + t
        u1, u2 = K @ (x / x[2]), K @ (y / y[2])
        if y[2] > 1 and 0 <= u1[0] < 1241 and 0 <= u1[1] < 376 and 0 <= u2[0] < 1241 and 0 <= u2[1] < 376:
            p1.append(u1[:2]); p2.append(u2[:2])
    p1 = np.array(p1) + rng.normal(0, 0.5, (300, 2))
    p2 = np.array(p2) + rng.normal(0, 0.5, (300, 2))
    out = rng.choice(300, 60, replace=False)
    p2[out] = rng.uniform([0, 0], [1241, 376], (60, 2))
    e, mask = cv2.findEssentialMat(p1, p2, K, cv2.RANSAC, 0.999, 1.0)
    e = e[:3]
    n, rr, tt, _ = cv2.recoverPose(e, p1, p2, K, mask=mask.copy())
    return {"seed": seed, "pts1": p1.tolist(), "pts2": p2.tolist(), "outliers": sorted(int(i) for i in out),
            "true_r": r.tolist(), "true_t": t.tolist(), "cv_inliers": int(mask.sum()), "cv_good": int(n),
            "cv_r": rr.tolist(), "cv_t": tt.ravel().tolist()}


def pnp_case(seed):
    rng = np.random.default_rng(1000 + seed)
    r = rot([rng.normal(0, 0.05), rng.uniform(-3.1, 3.1), rng.normal(0, 0.05)])
    t = rng.normal(0, 5, 3)
    pw, px = [], []
    while len(pw) < 200:
        pc = np.array([rng.uniform(-20, 20), rng.uniform(-3, 2), rng.uniform(3, 50)])
        u = K @ (pc / pc[2])
        if 0 <= u[0] < 1241 and 0 <= u[1] < 376:
            pw.append(r.T @ (pc - t)); px.append(u[:2])
    pw, px = np.array(pw), np.array(px) + rng.normal(0, 0.5, (200, 2))
    out = rng.choice(200, 50, replace=False)
    px[out] = rng.uniform([0, 0], [1241, 376], (50, 2))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(pw, px, K, None, iterationsCount=1000, reprojectionError=2.0,
                                               confidence=0.999, flags=cv2.SOLVEPNP_ITERATIVE)
    return {"seed": seed, "points_world": pw.tolist(), "pixels": px.tolist(), "outliers": sorted(int(i) for i in out),
            "true_r": r.tolist(), "true_t": t.tolist(), "cv_ok": bool(ok), "cv_inliers": int(len(inl)) if inl is not None else 0,
            "cv_r": rot(rvec.ravel()).tolist(), "cv_t": tvec.ravel().tolist()}


def main():
    fixture = {"opencv_version": cv2.__version__, "k": K.tolist(), "threshold_px": 1.0, "confidence": 0.999,
               "cases": [case(s) for s in range(12)]}
    path = os.path.join(ROOT, "tests", "fixtures", "opencv_essential.json")
    with open(path, "w") as f:
        json.dump(fixture, f)
    print(f"wrote {path} ({len(fixture['cases'])} cases, OpenCV {cv2.__version__})")
    pnp = {"opencv_version": cv2.__version__, "k": K.tolist(), "threshold_px": 2.0, "confidence": 0.999,
           "cases": [pnp_case(s) for s in range(12)]}
    path = os.path.join(ROOT, "tests", "fixtures", "opencv_pnp.json")
    with open(path, "w") as f:
        json.dump(pnp, f)
    print(f"wrote {path} ({len(pnp['cases'])} cases)")


if __name__ == "__main__":
    main()
