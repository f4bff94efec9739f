#!/usr/bin/env python3
"""SuperPoint and SuperGlue exports with random weights against reference forward passes.

The official weights cannot be downloaded here, so the exporters are checked with random
state dicts that have the official keys and shapes: the ONNX graphs (run by ONNX Runtime)
must reproduce a NumPy forward pass written from the papers, in float64 and in the
official channels-first layout (each network's equations, not the exporter's code). Exits
non-zero on any mismatch. Run by tools/test.sh (needs numpy, onnx and onnxruntime; the
runtime and `onnx` come from `supermvo models fetch`'s cache when not installed).

    python3 tools/models/test_superpoint_superglue.py [--cache DIR]
"""
import argparse
import glob
import importlib
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def cache_dir():
    if "--cache" in sys.argv[1:-1]:
        return sys.argv[sys.argv.index("--cache") + 1]
    return os.environ.get("SUPERMVO_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "supermvo")


def import_runtime(cache):
    try:
        import numpy  # noqa: F401
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
        return
    except ImportError:
        pass
    target = os.path.join(cache, "python")
    sys.path.insert(0, target)
    try:
        import numpy  # noqa: F401,F811
        import onnx  # noqa: F401,F811
        import onnxruntime  # noqa: F401,F811
        return
    except ImportError:
        pass
    # onnxruntime's wheel is in the cache already ('supermvo models fetch onnxruntime')
    wheels = glob.glob(os.path.join(cache, "wheels", "onnxruntime-*.whl"))
    print(f"[test] installing onnx, onnxruntime and numpy into {target}", flush=True)
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--target", target, "onnx==1.23.2", "numpy"]
                   + (wheels[:1] or ["onnxruntime"]), check=True)
    importlib.invalidate_caches()  # the directory was on sys.path before it had the packages



import_runtime(cache_dir())
import numpy as np  # noqa: E402


# ---- reference forward passes (float64, channels first) ---------------------------------

def conv2d(x, w, b):
    """'same' convolution, stride 1: x [C, H, W], w [O, C, k, k]."""
    o, c, k, _ = w.shape
    p = k // 2
    xp = np.pad(x, ((0, 0), (p, p), (p, p)))
    h, wd = x.shape[1:]
    cols = np.stack([xp[:, i:i + h, j:j + wd] for i in range(k) for j in range(k)], axis=1)  # [C, k*k, H, W]
    return np.einsum("ckhw,ock->ohw", cols, w.reshape(o, c, k * k)) + b[:, None, None]


def maxpool2(x):
    c, h, w = x.shape
    return x.reshape(c, h // 2, 2, w // 2, 2).max(axis=(2, 4))


def superpoint_reference(sd, image):
    """SuperPoint: a VGG-style shared encoder (conv3x3 + ReLU pairs, three 2x2 max pools),
    a detector head (conv3x3 256 + ReLU, conv1x1 65) and a descriptor head (conv3x3 256 +
    ReLU, conv1x1 D, L2 normalisation over channels)."""
    relu = lambda v: np.maximum(v, 0)
    x = image[None].astype(np.float64)
    for block, pool in [("1", True), ("2", True), ("3", True), ("4", False)]:
        x = relu(conv2d(x, sd[f"conv{block}a.weight"], sd[f"conv{block}a.bias"]))
        x = relu(conv2d(x, sd[f"conv{block}b.weight"], sd[f"conv{block}b.bias"]))
        if pool:
            x = maxpool2(x)
    semi = conv2d(relu(conv2d(x, sd["convPa.weight"], sd["convPa.bias"])), sd["convPb.weight"], sd["convPb.bias"])
    desc = conv2d(relu(conv2d(x, sd["convDa.weight"], sd["convDa.bias"])), sd["convDb.weight"], sd["convDb.bias"])
    return semi, desc / np.linalg.norm(desc, axis=0, keepdims=True)


def superglue_reference(sd, k0, k1, s0, s1, d0, d1, heads=4, iters=100):
    """SuperGlue: keypoint encoder MLP added to the descriptors, L alternating self/cross
    attentional message-passing layers (multi-head attention, message MLP on [x || m],
    residual), a final projection, scores <f_i, f_j> / sqrt(D), and a Sinkhorn solution of
    the optimal transport with one dustbin per image (score `bin_score`), in log space."""
    dim = sd["final_proj.weight"].shape[0]

    def conv1(x, key):  # x [C, N]
        return sd[f"{key}.weight"][:, :, 0] @ x + sd[f"{key}.bias"][:, None]

    def bn(x, key):
        return ((x - sd[f"{key}.running_mean"][:, None]) / np.sqrt(sd[f"{key}.running_var"][:, None] + 1e-5)
                * sd[f"{key}.weight"][:, None] + sd[f"{key}.bias"][:, None])

    def mlp(x, key, n):
        for i in range(n):
            x = conv1(x, f"{key}.{3 * i}")
            if i < n - 1:
                x = np.maximum(bn(x, f"{key}.{3 * i + 1}"), 0)
        return x

    def attention(key, x, src):
        q, k, v = (conv1(t, f"{key}.proj.{i}") for i, t in enumerate((x, src, src)))
        dh = dim // heads
        out = np.zeros_like(q)
        for h in range(heads):
            ch = np.arange(dh) * heads + h  # channel d * heads + h belongs to head h
            a = q[ch].T @ k[ch] / np.sqrt(dh)
            a = np.exp(a - a.max(axis=1, keepdims=True))
            a /= a.sum(axis=1, keepdims=True)
            out[ch] = (a @ v[ch].T).T
        return conv1(out, f"{key}.merge")

    n_enc = len([k for k in sd if k.startswith("kenc.encoder.") and k.endswith(".weight") and sd[k].ndim == 3])
    n_layers = len({k.split(".")[2] for k in sd if k.startswith("gnn.layers.")})
    x0 = d0.T + mlp(np.concatenate([k0.T, s0[None]]), "kenc.encoder", n_enc)
    x1 = d1.T + mlp(np.concatenate([k1.T, s1[None]]), "kenc.encoder", n_enc)
    for layer in range(n_layers):
        key = f"gnn.layers.{layer}"
        src0, src1 = (x1, x0) if layer % 2 else (x0, x1)
        m0 = mlp(np.concatenate([x0, attention(f"{key}.attn", x0, src0)]), f"{key}.mlp", 2)
        m1 = mlp(np.concatenate([x1, attention(f"{key}.attn", x1, src1)]), f"{key}.mlp", 2)
        x0, x1 = x0 + m0, x1 + m1
    f0, f1 = conv1(x0, "final_proj"), conv1(x1, "final_proj")
    scores = f0.T @ f1 / np.sqrt(dim)
    m, n = scores.shape
    alpha = float(sd["bin_score"])
    z = np.full((m + 1, n + 1), alpha)
    z[:m, :n] = scores
    norm = -np.log(m + n)
    log_mu = np.concatenate([np.full(m, norm), [np.log(n) + norm]])
    log_nu = np.concatenate([np.full(n, norm), [np.log(m) + norm]])
    lse = lambda a, axis: a.max(axis=axis) + np.log(np.exp(a - a.max(axis=axis, keepdims=True)).sum(axis=axis))
    u, v = np.zeros(m + 1), np.zeros(n + 1)
    for _ in range(iters):
        u = log_mu - lse(z + v[None, :], 1)
        v = log_nu - lse(z + u[:, None], 0)
    return z + u[:, None] + v[None, :] - norm


def superpoint_keypoints_reference(semi, coarse, radius=4, threshold=0.005, border=4, top_k=None):
    """SuperPoint's post-processing as MagicLeap's reference code describes it: softmax over
    the 65 channels, the dustbin dropped, 8x8 cells laid out at full resolution; NMS by max
    pooling with two recovery rounds; threshold; border removal; top-k; descriptors sampled
    bilinearly (grid_sample, align_corners) at (x - s/2 + 0.5) / (W s - s/2 - 0.5), then
    L2-normalised. Returns keypoints (x, y), scores and descriptors."""
    e = np.exp(semi - semi.max(axis=0, keepdims=True))
    prob = (e / e.sum(axis=0, keepdims=True))[:-1]
    h, w = semi.shape[1:]
    heat = prob.transpose(1, 2, 0).reshape(h, w, 8, 8).transpose(0, 2, 1, 3).reshape(h * 8, w * 8)

    def max_pool(a):
        p = np.pad(a, radius, constant_values=-np.inf)
        return np.lib.stride_tricks.sliding_window_view(p, (2 * radius + 1, 2 * radius + 1)).max(axis=(2, 3))
    keep = heat == max_pool(heat)
    for _ in range(2):
        supp = max_pool(keep.astype(np.float64)) > 0
        rest = np.where(supp, 0.0, heat)
        keep = keep | ((rest == max_pool(rest)) & ~supp)
    nms = np.where(keep, heat, 0.0)
    ys, xs = np.nonzero(nms > threshold)
    H, W = heat.shape
    ok = (ys >= border) & (ys < H - border) & (xs >= border) & (xs < W - border)
    ys, xs = ys[ok], xs[ok]
    sc = nms[ys, xs]
    order = np.argsort(-sc, kind="stable")[:top_k]
    ys, xs, sc = ys[order], xs[order], sc[order]
    gx = (xs - 3.5) / (w * 8 - 4.5) * (w - 1)
    gy = (ys - 3.5) / (h * 8 - 4.5) * (h - 1)
    x0, y0 = np.floor(gx).astype(int), np.floor(gy).astype(int)
    fx, fy = gx - x0, gy - y0
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    d = (coarse[:, y0, x0] * (1 - fx) * (1 - fy) + coarse[:, y0, x1] * fx * (1 - fy)
         + coarse[:, y1, x0] * (1 - fx) * fy + coarse[:, y1, x1] * fx * fy).T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.stack([xs, ys], 1).astype(np.float64), sc, d


# ---- the check ----------------------------------------------------------------------------

def random_state_dict(shapes, rng, scale, sharp=()):
    """Random weights of the given shapes; keys containing one of `sharp` get 8x larger
    weights (query and key projections, so that attention is peaked, not uniform)."""
    sd = {}
    for k, s in shapes.items():
        if k.endswith("running_var"):
            sd[k] = rng.uniform(0.5, 2.0, s)
        elif k.endswith("bias") or k.endswith("running_mean"):
            sd[k] = rng.normal(0, 0.1, s)
        elif k == "bin_score":
            sd[k] = np.array(1.0)
        elif len(s) > 1:
            fan_in = int(np.prod(s[1:]))
            sd[k] = rng.normal(0, scale * (8 if any(p in k for p in sharp) else 1) / np.sqrt(fan_in), s)
        else:  # batch-norm weights
            sd[k] = rng.uniform(0.5, 1.5, s)
    return {k: np.asarray(v, np.float32) for k, v in sd.items()}


def check_superglue(label, sd, rng, session, check, failures):
    import superglue_onnx
    m, n, dim = 37, 29, 256
    k0, k1 = rng.uniform(-0.7, 0.7, (m, 2)), rng.uniform(-0.7, 0.7, (n, 2))
    s0, s1 = rng.uniform(0, 1, m), rng.uniform(0, 1, n)
    d0, d1 = rng.normal(size=(m, dim)), rng.normal(size=(n, dim))
    d1[:20] = d0[:20] + 0.2 * rng.normal(size=(20, dim))  # 20 of the points seen in both
    k1[:20] = k0[:20] + 0.01 * rng.normal(size=(20, 2))
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    f = lambda a: a[None].astype(np.float32)
    (la,) = session(superglue_onnx.build(sd)).run(["log_assignment"], {
        "kpts0": f(k0), "kpts1": f(k1), "scores0": f(s0), "scores1": f(s1), "desc0": f(d0), "desc1": f(d1)})
    ref = superglue_reference({k: v.astype(np.float64) for k, v in sd.items()},
                              *(a.astype(np.float32).astype(np.float64) for a in (k0, k1, s0, s1, d0, d1)))
    check(f"SuperGlue {label}: log assignment", la[0], ref, 1e-4, 1e-5)
    mutual = lambda z: {(i, int(z[i, :-1].argmax())) for i in range(z.shape[0] - 1) if z[:-1, z[i, :-1].argmax()].argmax() == i}
    same = mutual(la[0]) == mutual(ref)
    print(f"[test] SuperGlue {label}: mutual best pairs: {len(mutual(ref))}, identical: {same}")
    if not same:
        failures.append(f"SuperGlue {label} matches")
    # the Sinkhorn constraint the last iteration enforces: every column of the plan sums to 1,
    # the dustbin column to m
    cols = np.exp(la[0]).sum(axis=0)
    check(f"SuperGlue {label}: plan column sums", cols, np.r_[np.ones(n), m], 1e-3, 1e-3)


def checker(failures):
    """check(what, got, want, atol, rtol): prints the largest difference and records `what`
    in `failures` where |got - want| > atol + rtol |want| anywhere."""
    def check(what, got, want, atol, rtol):
        err = np.abs(got - want)
        bad = err > atol + rtol * np.abs(want)
        print(f"[test] {what}: max abs difference {err.max():.2e} over {want.size} values (largest magnitude {np.abs(want).max():.3g})"
              + (" FAIL" if bad.any() else ""))
        if bad.any():
            failures.append(what)
    return check


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", default=cache_dir(), help="supermvo's cache (onnxruntime's wheel, Python packages)")
    ap.add_argument("--write", metavar="DIR", help="also write the random-weight superpoint.onnx and superglue.onnx "
                    "(18 layers) to DIR/models, for plumbing tests of the Rust front end")
    ap.add_argument("--image", nargs=3, metavar=("RAW", "W", "H"),
                    help="with --write: a grey image (raw u8, W x H, multiples of 8) to run the random-weight "
                    "SuperPoint on; its reference keypoints go to DIR/superpoint_expected.json")
    args = ap.parse_args()
    import onnxruntime as ort
    sys.path.insert(0, HERE)
    import superglue_onnx
    import superpoint_onnx

    rng = np.random.default_rng(7)
    failures = []

    def session(model):
        with tempfile.TemporaryDirectory() as tmp:  # through a file, as the cache would hold it
            path = os.path.join(tmp, "m.onnx")
            import onnx
            onnx.save(model, path)
            return ort.InferenceSession(path, providers=["CPUExecutionProvider"])

    check = checker(failures)

    # SuperPoint: a random image of 48 x 64 (multiples of 8)
    sd = random_state_dict(superpoint_onnx.shapes(), rng, 1.6)
    sd_read = sd
    image = rng.uniform(0, 1, (48, 64)).astype(np.float32)
    superpoint_model = superpoint_onnx.build(sd_read)
    semi, desc = session(superpoint_model).run(["scores_logits", "descriptors"], {"image": image[None, None]})
    ref_semi, ref_desc = superpoint_reference({k: v.astype(np.float64) for k, v in sd.items()}, image)
    check("SuperPoint detector logits", semi[0], ref_semi, 1e-4, 1e-4)
    check("SuperPoint descriptors", desc[0], ref_desc, 1e-5, 1e-4)

    # SuperGlue: 18 layers as the official model, and 2 layers (self, cross) with larger
    # weights, where a wrong head split or message path changes the output by far more;
    # 37 and 29 keypoints, 20 of them seen in both sets
    for label, layers, scale in (("18 layers", 18, 0.5), ("2 layers", 2, 1.0)):
        sg = random_state_dict(superglue_onnx.shapes(layers=layers), rng, scale, sharp=("attn.proj.0", "attn.proj.1"))
        check_superglue(label, sg, rng, session, check, failures)
        if layers == 18:
            superglue_model = superglue_onnx.build(sg)
    if args.write:
        import onnx
        os.makedirs(os.path.join(args.write, "models"), exist_ok=True)
        onnx.save(superpoint_model, os.path.join(args.write, "models", "superpoint.onnx"))
        onnx.save(superglue_model, os.path.join(args.write, "models", "superglue.onnx"))
        print(f"[test] random-weight superpoint.onnx and superglue.onnx written to {args.write}/models")
        if args.image:
            import json
            raw, w, h = args.image[0], int(args.image[1]), int(args.image[2])
            img = np.fromfile(raw, np.uint8).reshape(h, w).astype(np.float32) / 255
            semi, coarse = session(superpoint_model).run(["scores_logits", "descriptors"], {"image": img[None, None]})
            k, sc, d = superpoint_keypoints_reference(semi[0].astype(np.float64), coarse[0].astype(np.float64), top_k=None)
            with open(os.path.join(args.write, "superpoint_expected.json"), "w") as f:
                json.dump({"keypoints": k.tolist(), "scores": sc.tolist(), "descriptors": d.tolist()}, f)
            print(f"[test] reference SuperPoint keypoints ({len(k)}) written")
    if failures:
        sys.exit(f"[test] FAILED: {', '.join(failures)}")
    print("[test] SuperPoint and SuperGlue exports match the reference forward passes")


if __name__ == "__main__":
    main()
