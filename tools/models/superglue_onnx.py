"""SuperGlue (Sarlin, DeTone, Malisiewicz and Rabinovich, CVPR 2020) as an ONNX graph, from
the state dict of the official `superglue_outdoor.pth` / `superglue_indoor.pth` (MagicLeap's
file layout: keypoint encoder `kenc.encoder.*`, attentional GNN `gnn.layers.*` alternating
self and cross, `final_proj`, the dustbin score `bin_score`).

Inputs  `kpts0` [1, M, 2], `kpts1` [1, N, 2]: keypoints normalised as SuperGlue does,
        (kpts - size / 2) / (0.7 max(size)); `scores0` [1, M], `scores1` [1, N]: detection
        scores; `desc0` [1, M, D], `desc1` [1, N, D]: descriptors.
Output  `log_assignment` [1, M + 1, N + 1]: the log transport plan after the Sinkhorn
        iterations (dustbins last), so the caller selects mutual best matches above its
        threshold exactly as for LightGlue.
Implementation notes: 1x1 Conv1d layers are MatMuls on [1, N, D] (points-major) tensors;
batch norms (eval mode) are folded into the preceding layer; the multi-head split follows
the official `view(b, dim, heads, n)`, so channel c belongs to head c % heads; the Sinkhorn
loop is unrolled.
"""
import math

import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lightglue_onnx  # noqa: E402

BN_EPS = 1e-5


class _G(lightglue_onnx._G):
    """The graph builder of the LightGlue exporter, reading weights in float64 so batch
    norms fold without rounding twice."""

    def w(self, key):
        k = self.prefix + key
        if k not in self.sd:
            raise KeyError(f"weight '{k}' missing from the checkpoint (is it SuperGlue?)")
        return np.asarray(self.sd[k], np.float64)

    def conv1(self, x, key, bn=None):
        """A 1x1 Conv1d on [1, N, C_in] -> [1, N, C_out], with an optional following batch norm folded in."""
        wt, b = self.w(f"{key}.weight")[:, :, 0], self.w(f"{key}.bias")
        if bn is not None:
            scale = self.w(f"{bn}.weight") / np.sqrt(self.w(f"{bn}.running_var") + BN_EPS)
            wt, b = wt * scale[:, None], (b - self.w(f"{bn}.running_mean")) * scale + self.w(f"{bn}.bias")
        return self.op("Add", [self.op("MatMul", [x, self.c(wt.T)]), self.c(b)])

    def mlp(self, x, key, n_layers):
        """SuperGlue's MLP: Conv1d, BatchNorm1d, ReLU, ... Conv1d (indices 0, 1, 3, 4, ... )."""
        for i in range(n_layers):
            last = i == n_layers - 1
            x = self.conv1(x, f"{key}.{3 * i}", None if last else f"{key}.{3 * i + 1}")
            if not last:
                x = self.op("Relu", [x])
        return x


def build(sd, prefix="", name="superglue", heads=4, sinkhorn_iterations=100):
    g = _G(sd, prefix)
    dim = g.w("final_proj.weight").shape[0]
    n_enc = sum(1 for k in sd if k.startswith(prefix + "kenc.encoder.") and k.endswith(".weight")
                and np.asarray(sd[k]).ndim == 3)
    n_gnn = 1 + max(int(k[len(prefix + "gnn.layers."):].split(".")[0]) for k in sd if k.startswith(prefix + "gnn.layers."))
    d_head = dim // heads
    f32 = TensorProto.FLOAT

    def encode(kpts, scores, desc):
        inp = g.op("Concat", [kpts, g.op("Unsqueeze", [scores, g.c(np.array([2], np.int64), np.int64)])], axis=2)
        return g.op("Add", [desc, g.mlp(inp, "kenc.encoder", n_enc)])

    split_shape = g.c(np.array([1, -1, d_head, heads], np.int64), np.int64)
    merge_shape = g.c(np.array([1, -1, dim], np.int64), np.int64)

    def to_heads(x):  # [1, N, dim] -> [1, heads, N, d_head], channel c = d * heads + h
        return g.op("Transpose", [g.op("Reshape", [x, split_shape])], perm=[0, 3, 1, 2])

    def propagate(layer, x, source):
        key = f"gnn.layers.{layer}"
        q, k, v = (to_heads(g.conv1(t, f"{key}.attn.proj.{i}")) for i, t in enumerate((x, source, source)))
        sim = g.op("Mul", [g.op("MatMul", [q, g.op("Transpose", [k], perm=[0, 1, 3, 2])]), g.c(np.float32(1 / math.sqrt(d_head)))])
        msg = g.op("MatMul", [g.op("Softmax", [sim], axis=-1), v])  # [1, heads, N, d_head]
        msg = g.op("Reshape", [g.op("Transpose", [msg], perm=[0, 2, 3, 1]), merge_shape])
        msg = g.conv1(msg, f"{key}.attn.merge")
        return g.mlp(g.op("Concat", [x, msg], axis=2), f"{key}.mlp", 2)

    d0, d1 = encode("kpts0", "scores0", "desc0"), encode("kpts1", "scores1", "desc1")
    for layer in range(n_gnn):
        cross = layer % 2 == 1  # the official names: ['self', 'cross'] * 9
        delta0 = propagate(layer, d0, d1 if cross else d0)
        delta1 = propagate(layer, d1, d0 if cross else d1)
        d0, d1 = g.op("Add", [d0, delta0]), g.op("Add", [d1, delta1])
    m0, m1 = g.conv1(d0, "final_proj"), g.conv1(d1, "final_proj")
    scores = g.op("Mul", [g.op("MatMul", [m0, g.op("Transpose", [m1], perm=[0, 2, 1])]), g.c(np.float32(1 / math.sqrt(dim)))])

    # optimal transport with a dustbin row and column, in log space
    def count(x):
        return g.op("Cast", [g.op("Gather", [g.op("Shape", [x]), g.c(np.int64(1), np.int64)], axis=0)], to=f32)
    m, n = count("kpts0"), count("kpts1")
    alpha = g.c(np.asarray(g.w("bin_score"), np.float32).reshape(1, 1, 1))
    ones_col = g.op("Slice", [g.op("Mul", [scores, g.c(np.float32(0))]), g.c(np.array([0], np.int64), np.int64),
                              g.c(np.array([1], np.int64), np.int64), g.c(np.array([2], np.int64), np.int64)])  # [1, M, 1] zeros
    ones_row = g.op("Slice", [g.op("Mul", [scores, g.c(np.float32(0))]), g.c(np.array([0], np.int64), np.int64),
                              g.c(np.array([1], np.int64), np.int64), g.c(np.array([1], np.int64), np.int64)])  # [1, 1, N] zeros
    top = g.op("Concat", [scores, g.op("Add", [ones_col, alpha])], axis=2)
    bottom = g.op("Concat", [g.op("Add", [ones_row, alpha]), alpha], axis=2)
    couplings = g.op("Concat", [top, bottom], axis=1)  # [1, M + 1, N + 1]
    norm = g.op("Neg", [g.op("Log", [g.op("Add", [m, n])])])
    log_mu = g.op("Concat", [g.op("Add", [g.op("Reshape", [ones_col, g.c(np.array([1, -1], np.int64), np.int64)]), norm]),
                             g.op("Reshape", [g.op("Add", [g.op("Log", [n]), norm]), g.c(np.array([1, 1], np.int64), np.int64)])], axis=1)
    log_nu = g.op("Concat", [g.op("Add", [g.op("Reshape", [ones_row, g.c(np.array([1, -1], np.int64), np.int64)]), norm]),
                             g.op("Reshape", [g.op("Add", [g.op("Log", [m]), norm]), g.c(np.array([1, 1], np.int64), np.int64)])], axis=1)
    axis2, axis1 = g.c(np.array([2], np.int64), np.int64), g.c(np.array([1], np.int64), np.int64)
    u = g.op("Mul", [log_mu, g.c(np.float32(0))])  # [1, M + 1]
    v = g.op("Mul", [log_nu, g.c(np.float32(0))])  # [1, N + 1]
    for _ in range(sinkhorn_iterations):
        z_v = g.op("Add", [couplings, g.op("Unsqueeze", [v, axis1])])
        u = g.op("Sub", [log_mu, g.op("ReduceLogSumExp", [z_v, axis2], keepdims=0)])
        z_u = g.op("Add", [couplings, g.op("Unsqueeze", [u, axis2])])
        v = g.op("Sub", [log_nu, g.op("ReduceLogSumExp", [z_u, axis1], keepdims=0)])
    z = g.op("Add", [g.op("Add", [couplings, g.op("Unsqueeze", [u, axis2])]), g.op("Unsqueeze", [v, axis1])])
    g.op("Sub", [z, norm], out="log_assignment")

    d_in = dim
    graph = helper.make_graph(
        g.nodes, name,
        [helper.make_tensor_value_info("kpts0", f32, [1, "M", 2]), helper.make_tensor_value_info("kpts1", f32, [1, "N", 2]),
         helper.make_tensor_value_info("scores0", f32, [1, "M"]), helper.make_tensor_value_info("scores1", f32, [1, "N"]),
         helper.make_tensor_value_info("desc0", f32, [1, "M", d_in]), helper.make_tensor_value_info("desc1", f32, [1, "N", d_in])],
        [helper.make_tensor_value_info("log_assignment", f32, [1, "M1", "N1"])],
        g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="supermvo-export")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def shapes(dim=256, layers=18, encoder=(32, 64, 128, 256)):
    """The official state dict's keys and shapes (for random-weight tests)."""
    out = {}
    chans = [3, *encoder, dim]
    for i in range(1, len(chans)):
        j = 3 * (i - 1)
        out[f"kenc.encoder.{j}.weight"], out[f"kenc.encoder.{j}.bias"] = (chans[i], chans[i - 1], 1), (chans[i],)
        if i < len(chans) - 1:
            for s in ("weight", "bias", "running_mean", "running_var"):
                out[f"kenc.encoder.{j + 1}.{s}"] = (chans[i],)
    for layer in range(layers):
        key = f"gnn.layers.{layer}"
        for p in ["attn.merge", "attn.proj.0", "attn.proj.1", "attn.proj.2"]:
            out[f"{key}.{p}.weight"], out[f"{key}.{p}.bias"] = (dim, dim, 1), (dim,)
        out[f"{key}.mlp.0.weight"], out[f"{key}.mlp.0.bias"] = (2 * dim, 2 * dim, 1), (2 * dim,)
        for s in ("weight", "bias", "running_mean", "running_var"):
            out[f"{key}.mlp.1.{s}"] = (2 * dim,)
        out[f"{key}.mlp.3.weight"], out[f"{key}.mlp.3.bias"] = (dim, 2 * dim, 1), (dim,)
    out["final_proj.weight"], out["final_proj.bias"] = (dim, dim, 1), (dim,)
    out["bin_score"] = ()
    return out
