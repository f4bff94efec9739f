#!/usr/bin/env python3
"""Benchmark: the learned front end in Rust (ort) next to Python onnxruntime, in one run.

Both run the same ONNX files from the model cache with the same settings (intra-op
threads 2, inter-op 1, default graph optimisation) on inputs of the same shapes: XFeat on
a KITTI frame resized to multiples of 32, LighterGlue at 1024 and 2048 keypoints. The
script alternates the Rust and the Python measurement --rounds times and reports the
median of the per-round medians, and their ratio (Rust / Python; <= 1.05 wanted).
Rust's full extraction (resize + network + NMS, scoring, top-k, descriptor sampling) and
full matching (network + mutual filtering) are reported too.

    python3 tools/bench_frontend.py [--seq 00] [--rounds 5] [--runs 15]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences"))


def cache():
    return os.environ.get("SUPERMVO_CACHE") or os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "supermvo")


def python_medians(runs, threads, size, keypoints):
    import onnxruntime as ort
    from PIL import Image
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
    models = os.path.join(cache(), "models")
    xs = ort.InferenceSession(os.path.join(models, "xfeat.onnx"), opts, providers=["CPUExecutionProvider"])
    ls = ort.InferenceSession(os.path.join(models, "lighterglue.onnx"), opts, providers=["CPUExecutionProvider"])

    def med(fn):
        for _ in range(3):
            fn()
        t = []
        for _ in range(runs):
            s = time.perf_counter(); fn(); t.append((time.perf_counter() - s) * 1e3)
        return statistics.median(t)

    w, h = size
    img = np.asarray(Image.open(os.path.join(SHARED, "00", "image_0", "000000.png")).convert("L").resize((w, h), Image.BILINEAR), np.float32) / 255
    out = {"xfeat_network_ms": med(lambda: xs.run(None, {"image": img[None, None]}))}
    rng = np.random.default_rng(0)
    for k in keypoints:
        kp = rng.uniform(-1, 1, (1, k, 2)).astype(np.float32)
        d = rng.normal(size=(1, k, 64)).astype(np.float32)
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        feeds = {"kpts0": kp, "kpts1": kp[:, ::-1].copy(), "desc0": d, "desc1": d[:, ::-1].copy()}
        out[f"lighterglue_{k}_network_ms"] = med(lambda: ls.run(None, feeds))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seq", default="00")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--bin", default=os.path.join(ROOT, "target", "release", "supermvo"))
    args = ap.parse_args()
    a = os.path.join(SHARED, args.seq, "image_0", "000000.png")
    b = os.path.join(SHARED, args.seq, "image_0", "000001.png")
    if not os.path.exists(a):
        sys.exit(f"bench_frontend: {a} not found")
    rust, py = [], []
    for _ in range(args.rounds):
        r = json.loads(subprocess.run([args.bin, "bench", "frontend", a, b, "--runs", str(args.runs)], check=True,
                                      capture_output=True, text=True).stdout)
        rust.append(r)
        ks = [k for k in (1024, 2048) if r[f"keypoints_{k}"] == k]
        py.append(python_medians(args.runs, r["threads"], tuple(r["input_size"]), ks))
    med = lambda rows, key: statistics.median(x[key] for x in rows)
    w, h = rust[0]["input_size"]
    print(f"KITTI {args.seq} frames 0-1, network input {w}x{h}, {rust[0]['threads']} intra-op threads, "
          f"{args.rounds} rounds x {args.runs} calls, {os.cpu_count()} CPUs")
    print(f"{'what':<34} {'Rust ms':>9} {'Python ms':>10} {'ratio':>7}")
    for key, label in [("xfeat_network_ms", "XFeat network"), ("lighterglue_1024_network_ms", "LighterGlue network, 1024 kpts"),
                       ("lighterglue_2048_network_ms", "LighterGlue network, 2048 kpts")]:
        if key in py[0]:
            print(f"{label:<34} {med(rust, key):>9.2f} {med(py, key):>10.2f} {med(rust, key) / med(py, key):>7.3f}")
    for key, label in [("xfeat_extract_ms", "XFeat full extraction (Rust)"), ("lighterglue_1024_match_ms", "LighterGlue full match, 1024"),
                       ("lighterglue_2048_match_ms", "LighterGlue full match, 2048")]:
        print(f"{label:<34} {med(rust, key):>9.2f} {'':>10} {'':>7}")


if __name__ == "__main__":
    main()
