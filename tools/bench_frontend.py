#!/usr/bin/env python3
"""Benchmark: the learned front end in Rust (ort) next to Python onnxruntime, in one run.

Both run the same ONNX files from the model cache with the same settings (intra-op
threads 2, inter-op 1, default graph optimisation, subnormals flushed to zero) on inputs of the same shapes: XFeat on
a KITTI frame resized to multiples of 32, LighterGlue at 1024 and 2048 keypoints on the
very keypoints and descriptors XFeat found on the two frames (the Rust side writes them with
`--dump`), with point pruning (width_confidence 0.95, the default), without it (-1), and
with pruning and early stopping (depth_confidence 0.95; off by default). The
script alternates the Rust and the Python measurement --rounds times and reports the
median of the per-round medians, and their ratio (Rust / Python; <= 1.05 wanted).
Rust's full extraction (resize + network + NMS, scoring, top-k, descriptor sampling) and
full matching (network + mutual filtering) are reported too. When `supermvo models fetch
aliked lightglue` has run, ALIKED (one graph: network, detection and descriptors, on the
full frame, 2048 keypoints requested) and LightGlue (on the keypoints ALIKED keeps of 1024
and 2048 requested; LightGlue's pruning and early stopping, and neither) are timed the same
way with fewer calls (`--aliked-runs`, 5).

    python3 tools/bench_frontend.py [--seq 00] [--rounds 5] [--runs 15]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.path.normpath(os.path.join(ROOT, "..", "shared", "data", "kitti", "sequences"))


def cache():
    return os.environ.get("SUPERMVO_CACHE") or os.path.join(os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "supermvo")


# numpy, onnx and onnxruntime: the system's, or those the model scripts installed in the cache
sys.path.append(os.path.join(cache(), "python"))
try:
    import numpy as np
    import onnx  # noqa: F401
    import onnxruntime as ort
except ImportError as e:
    sys.exit(f"bench_frontend: {e}; run `bash tools/test.sh` once (it installs numpy, onnx and onnxruntime into "
             f"{os.path.join(cache(), 'python')}) or `pip install numpy onnx onnxruntime`")


def session_options(threads):
    """The Rust sessions' settings: `threads` intra-op threads, one inter-op, subnormals flushed."""
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
    opts.add_session_config_entry("session.set_denormal_as_zero", "1")
    return opts


def matcher_inputs(dump, prefix, m, n, dim):
    """The keypoints and descriptors the Rust side wrote with `--dump` (`{prefix}_kpts0.f32`...)."""
    load = lambda name, count, width: np.fromfile(os.path.join(dump, f"{prefix}_{name}.f32"), "<f4").reshape(1, count, width)
    return {"kpts0": load("kpts0", m, 2), "kpts1": load("kpts1", n, 2), "desc0": load("desc0", m, dim), "desc1": load("desc1", n, dim)}


def settings(feeds, minimum, depth):
    """`feeds` with the matcher's pruning (`min_matchability`) and early stopping set."""
    return dict(feeds, min_matchability=np.array(minimum, np.float32), depth_confidence=np.array(depth, np.float32))


def python_medians(runs, threads, size, keypoints, dump, sizes, rust):
    opts = session_options(threads)
    models = os.path.join(cache(), "models")
    xs = ort.InferenceSession(os.path.join(models, "xfeat.onnx"), opts, providers=["CPUExecutionProvider"])
    ls = ort.InferenceSession(os.path.join(models, "lighterglue.onnx"), opts, providers=["CPUExecutionProvider"])

    def med(fn, n=runs):
        for _ in range(3):
            fn()
        t = []
        for _ in range(n):
            s = time.perf_counter(); fn(); t.append((time.perf_counter() - s) * 1e3)
        return statistics.median(t)

    w, h = size
    img = np.fromfile(os.path.join(dump, "xfeat_input.f32"), "<f4").reshape(h, w)  # the pixels Rust's XFeat ran on
    out = {"xfeat_network_ms": med(lambda: xs.run(None, {"image": img[None, None]}))}
    for k in keypoints:
        (m, n), dim = sizes[k]
        feeds = matcher_inputs(dump, f"lighterglue_{k}", m, n, dim)
        for key, minimum, depth in ((f"lighterglue_{k}_network_ms", 0.05, -1.0),
                                    (f"lighterglue_{k}_network_unpruned_ms", -1.0, -1.0),
                                    (f"lighterglue_{k}_network_early_stop_ms", 0.05, 0.95)):
            f = settings(feeds, minimum, depth)
            out[key] = med(lambda: ls.run(None, f))
    if "aliked_runs" in rust:  # ALIKED + LightGlue, fewer calls (seconds each)
        ar = rust["aliked_runs"]
        als = ort.InferenceSession(os.path.join(models, "aliked.onnx"), opts, providers=["CPUExecutionProvider"])
        lgs = ort.InferenceSession(os.path.join(models, "lightglue.onnx"), opts, providers=["CPUExecutionProvider"])
        full = np.fromfile(os.path.join(dump, "frame_a.f32"), "<f4").reshape(rust["frame_size"][1], rust["frame_size"][0])
        out["aliked_extract_ms"] = med(lambda: als.run(None, {"image": full[None, None], "top_k": np.array([2048], np.int64)}), ar)
        for k in (1024, 2048):
            m, n = rust[f"aliked_{k}_sizes"]
            feeds = matcher_inputs(dump, f"lightglue_{k}", m, n, 128)
            for key, minimum, depth in ((f"lightglue_{k}_network_ms", 0.01, 0.95), (f"lightglue_{k}_network_full_ms", -1.0, -1.0)):
                f = settings(feeds, minimum, depth)
                out[key] = med(lambda: lgs.run(None, f), ar)
    return out


def matmul_floor(threads, dump, size, calls=5):
    """Where one pruned LighterGlue call at 1024 keypoints spends its time, from ONNX Runtime's
    own profiler (Python side, same settings as above), and how fast this machine's ONNX
    Runtime multiplies float32 matrices at best (the fastest of 40 calls of a lone MatMul, same
    threads, at three shapes): the network's MatMul FLOPs over that rate bound the call from
    below whatever the rest of the graph does."""
    import collections
    from onnx import TensorProto, helper
    opts = session_options(threads)
    opts.enable_profiling = True
    opts.profile_file_prefix = os.path.join(dump, "lighterglue_profile")
    ls = ort.InferenceSession(os.path.join(cache(), "models", "lighterglue.onnx"), opts, providers=["CPUExecutionProvider"])
    (m, n), dim = size
    feeds = settings(matcher_inputs(dump, "lighterglue_1024", m, n, dim), 0.05, -1.0)
    for _ in range(3):
        ls.run(None, feeds)
    for _ in range(calls):
        ls.run(None, feeds)
    with open(ls.end_profiling()) as f:
        events = json.load(f)
    runs = [e["dur"] for e in events if e.get("name") == "model_run"]  # warm-up calls included, as in the kernel sums
    time_by_op, flop = collections.Counter(), 0
    for e in events:
        args = e.get("args", {})
        if e.get("cat") != "Node" or not e["name"].endswith("_kernel_time") or "op_name" not in args:
            continue
        time_by_op[args["op_name"]] += e["dur"]
        if args["op_name"] in ("MatMul", "FusedMatMul", "Gemm"):
            a = list(args["input_type_shape"][0].values())[0]  # no transposed A in our graphs
            out = list(args["output_type_shape"][0].values())[0]
            flop += 2 * int(np.prod(out)) * a[-1]
    total = len(runs)
    flop /= total
    mm_ms = sum(time_by_op[op] for op in ("MatMul", "FusedMatMul", "Gemm")) / total / 1e3
    popts = session_options(threads)
    peak = 0.0
    for rows, inner, cols in ((1024, 1024, 1024), (1024, 96, 1024), (1024, 192, 192)):  # a square one and the network's own
        g = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["c"])], "peak",
                              [helper.make_tensor_value_info("a", TensorProto.FLOAT, [rows, inner]),
                               helper.make_tensor_value_info("b", TensorProto.FLOAT, [inner, cols])],
                              [helper.make_tensor_value_info("c", TensorProto.FLOAT, [rows, cols])])
        model = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        ps = ort.InferenceSession(model.SerializeToString(), popts, providers=["CPUExecutionProvider"])
        rng = np.random.default_rng(0)
        ab = {"a": rng.random((rows, inner), np.float32), "b": rng.random((inner, cols), np.float32)}
        t = []
        for _ in range(40):
            start = time.perf_counter(); ps.run(None, ab); t.append(time.perf_counter() - start)
        peak = max(peak, 2 * rows * inner * cols / min(t) / 1e9)  # the best call: a bound, not a typical rate
    return {"call_ms": statistics.median(runs) / 1e3, "kernel_ms": sum(time_by_op.values()) / total / 1e3, "matmul_ms": mm_ms,
            "gflop": flop / 1e9, "peak_gflops": peak, "floor_ms": flop / 1e9 / peak * 1e3}


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
    with tempfile.TemporaryDirectory() as dump:
        for _ in range(args.rounds):
            r = json.loads(subprocess.run([args.bin, "bench", "frontend", a, b, "--runs", str(args.runs), "--dump", dump],
                                          check=True, capture_output=True, text=True).stdout)
            rust.append(r)
            ks = [k for k in (1024, 2048) if r[f"keypoints_{k}"] == k]
            sizes = {k: (r[f"sizes_{k}"], r[f"dim_{k}"]) for k in ks}
            py.append(python_medians(args.runs, r["threads"], tuple(r["input_size"]), ks, dump, sizes, r))
        floor = matmul_floor(rust[0]["threads"], dump, sizes[1024]) if 1024 in sizes else None
    med = lambda rows, key: statistics.median(x[key] for x in rows)
    w, h = rust[0]["input_size"]
    print(f"KITTI {args.seq} frames 0-1, network input {w}x{h}, {rust[0]['threads']} intra-op threads, "
          f"{args.rounds} rounds x {args.runs} calls, {os.cpu_count()} CPUs")
    print(f"{'what':<38} {'Rust ms':>9} {'Python ms':>10} {'ratio':>7}")
    rows = [("xfeat_network_ms", "XFeat network")]
    for k in (1024, 2048):
        rows += [(f"lighterglue_{k}_network_ms", f"LighterGlue network, {k}, pruned"),
                 (f"lighterglue_{k}_network_unpruned_ms", f"LighterGlue network, {k}, no pruning"),
                 (f"lighterglue_{k}_network_early_stop_ms", f"LighterGlue network, {k}, pruned+stop")]
    if "aliked_runs" in rust[0]:
        rows.append(("aliked_extract_ms", "ALIKED, whole graph, full frame"))
        for k in (1024, 2048):
            m, n = rust[0][f"aliked_{k}_sizes"]
            rows += [(f"lightglue_{k}_network_ms", f"LightGlue, {m}+{n}, pruned+stop"),
                     (f"lightglue_{k}_network_full_ms", f"LightGlue, {m}+{n}, full")]
    for key, label in rows:
        if key in py[0]:
            print(f"{label:<38} {med(rust, key):>9.2f} {med(py, key):>10.2f} {med(rust, key) / med(py, key):>7.3f}")
    for key, label in [("xfeat_extract_ms", "XFeat full extraction (Rust)"), ("lighterglue_1024_match_ms", "LighterGlue full match, 1024"),
                       ("lighterglue_2048_match_ms", "LighterGlue full match, 2048")]:
        print(f"{label:<38} {med(rust, key):>9.2f} {'':>10} {'':>7}")
    for k in (1024, 2048):
        if f"lighterglue_{k}_kept" in rust[0]:
            kept, mt = rust[0][f"lighterglue_{k}_kept"], rust[0][f"lighterglue_{k}_matches"]
            print(f"{k} keypoints: {kept[0]} and {kept[1]} reach the last layer; matches unpruned {mt['unpruned']}, "
                  f"pruned {mt['pruned']} ({mt['common']} of them also unpruned), pruned+stop {mt['early_stop']} "
                  f"({mt['early_stop_common']}) after {rust[0][f'lighterglue_{k}_early_stop_layers']} of 6 layers")
    if floor:
        print(f"LighterGlue 1024 pruned under the profiler (Python): {floor['call_ms']:.1f} ms a call, MatMul kernels "
              f"{floor['matmul_ms']:.1f} ms for {floor['gflop']:.2f} GFLOP ({floor['gflop'] / floor['matmul_ms'] * 1e3:.0f} GFLOP/s), "
              f"other kernels {floor['kernel_ms'] - floor['matmul_ms']:.1f} ms")
        print(f"ONNX Runtime's fastest MatMul on this machine (best of 40 calls, 3 shapes): {floor['peak_gflops']:.0f} GFLOP/s "
              f"-> the network's MatMuls alone need at least {floor['floor_ms']:.1f} ms")
    if "aliked_runs" in rust[0]:
        print(f"ALIKED/LightGlue: {rust[0]['aliked_runs']} calls per measurement; ALIKED keypoints scoring above 0.2 "
              f"among the 1024 / 2048 requested: {rust[0]['aliked_1024_sizes']} / {rust[0]['aliked_2048_sizes']}")
        for k in (1024, 2048):
            mt = rust[0][f"lightglue_{k}_matches"]
            print(f"LightGlue {k}: matches full {mt['full']}, pruned+stop {mt['adaptive']} ({mt['common']} of them also full) "
                  f"after {rust[0][f'lightglue_{k}_layers']} of 9 layers")


if __name__ == "__main__":
    main()
