"""ALIKED (Zhao et al., IEEE TIM 2023) as one ONNX graph, built from its state dict.

Input   `image` [1, 1, H, W] float32 grayscale in [0, 1], any H and W (the graph pads to
        multiples of 32 by edge replication and crops the maps back, as ALIKED does);
        `top_k` [1] int64: how many keypoints to return (at most H * W).
Outputs `keypoints` [1, K, 2] (x, y) in pixels, sub-pixel;
        `detection_scores` [1, K]: the score at each keypoint's integer location after
        non-maximum suppression, sorted descending (ALIKED's detection threshold, 0.2 by
        default, applies to these; the caller filters, so the threshold stays configurable);
        `scores` [1, K]: the score map sampled bilinearly at the sub-pixel keypoint;
        `descriptors` [1, K, 128]: unit-length SDDH descriptors.

The network: four blocks (two plain, two with deformable 3x3 convolutions, offsets clamped
to a quarter of the map's larger side), multi-scale aggregation (1x1 conv, SELU, bilinear
upsampling with aligned corners), a small score head with a sigmoid, and the L2-normalised
feature map. Detection (DKD): a 5x5 non-maximum suppression with two recovery rounds, a
2-pixel border removed, top-k, and a soft-argmax in each 5x5 window (temperature 0.1).
Description (SDDH): a 3x3 feature patch at each keypoint predicts 16 sample offsets, the
features sampled there pass a 1x1 conv and SELU and are aggregated by per-position weights.
Batch norms (eps 1e-5) are folded into their convolutions; the grayscale image stands in for
ALIKED's RGB copy of it by summing the first convolution's weights over the three channels.
"""
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

BN_EPS = 1e-5
RADIUS = 2  # DKD's NMS and soft-detection radius
TEMPERATURE = 0.1
N_POS = 16  # SDDH sample positions (aliked-n16)


class _G:
    def __init__(self, sd):
        self.sd, self.nodes, self.inits, self.n = sd, [], [], 0

    def w(self, key):
        if key not in self.sd:
            raise KeyError(f"weight '{key}' missing from the checkpoint")
        return np.asarray(self.sd[key], np.float32)

    def c(self, arr, dtype=np.float32):
        self.n += 1
        name = f"c{self.n}"
        self.inits.append(numpy_helper.from_array(np.asarray(arr, dtype=dtype), name))
        return name

    def i(self, *values):
        return self.c(np.array(values, np.int64), np.int64)

    def op(self, op, inputs, out=None, **attrs):
        self.n += 1
        out = out or f"{op.lower()}_{self.n}"
        self.nodes.append(helper.make_node(op, inputs, [out], name=f"n{self.n}_{op}", **attrs))
        return out

    def ops(self, op, inputs, n_out, **attrs):
        self.n += 1
        outs = [f"{op.lower()}_{self.n}_{k}" for k in range(n_out)]
        self.nodes.append(helper.make_node(op, inputs, outs, name=f"n{self.n}_{op}", **attrs))
        return outs

    def bn_fold(self, w, b, key):
        gamma, beta = self.w(f"{key}.weight"), self.w(f"{key}.bias")
        mean, var = self.w(f"{key}.running_mean"), self.w(f"{key}.running_var")
        s = gamma / np.sqrt(var + BN_EPS)
        b = np.zeros(w.shape[0], np.float32) if b is None else b
        return (w * s[:, None, None, None]).astype(np.float32), ((b - mean) * s + beta).astype(np.float32)

    def conv(self, x, w, b=None, pad=None):
        k = w.shape[-1]
        pad = k // 2 if pad is None else pad
        inputs = [x, self.c(w)] + ([self.c(b)] if b is not None else [])
        return self.op("Conv", inputs, kernel_shape=[k, k], pads=[pad] * 4)

    def selu(self, x):
        return self.op("Selu", [x])

    def max_side_quarter(self, x):
        """max(h, w) / 4 of a [1, C, h, w] tensor, as a float scalar."""
        hw = self.op("Cast", [self.op("Slice", [self.op("Shape", [x]), self.i(2), self.i(4)])], to=TensorProto.FLOAT)
        return self.op("Div", [self.op("ReduceMax", [hw], keepdims=0), self.c(np.float32(4))])

    def conv_bn(self, x, key, bn, deformable, w_override=None):
        """conv (plain or deformable) followed by its folded batch norm."""
        if not deformable:
            w = self.w(f"{key}.weight") if w_override is None else w_override
            wf, bf = self.bn_fold(w, None, bn)
            return self.conv(x, wf, bf)
        limit = self.max_side_quarter(x)
        offset = self.conv(x, self.w(f"{key}.offset_conv.weight"), self.w(f"{key}.offset_conv.bias"))
        offset = self.op("Clip", [offset, self.op("Neg", [limit]), limit])
        wf, bf = self.bn_fold(self.w(f"{key}.regular_conv.weight"), None, bn)
        return self.op("DeformConv", [x, self.c(wf), offset, self.c(bf)], kernel_shape=[3, 3], pads=[1, 1, 1, 1])

    def res_block(self, x, key, deformable):
        out = self.selu(self.conv_bn(x, f"{key}.conv1", f"{key}.bn1", deformable))
        out = self.conv_bn(out, f"{key}.conv2", f"{key}.bn2", deformable)
        identity = self.conv(x, self.w(f"{key}.downsample.weight"), self.w(f"{key}.downsample.bias"))
        return self.selu(self.op("Add", [out, identity]))

    def l2_normalise(self, x, axis):
        norm = self.op("ReduceL2", [x, self.i(axis)], keepdims=1)
        return self.op("Div", [x, self.op("Max", [norm, self.c(np.float32(1e-12))])])


def build(sd):
    g = _G(sd)
    f32, i64 = TensorProto.FLOAT, TensorProto.INT64
    # ---- pad to multiples of 32 (edge), as ALIKED's InputPadder: (32 - n % 32) % 32, half before
    shape = g.op("Shape", ["image"])
    hw = g.op("Slice", [shape, g.i(2), g.i(4)])  # [H, W]
    total = g.op("Mod", [g.op("Sub", [g.i(32, 32), g.op("Mod", [hw, g.i(32, 32)])]), g.i(32, 32)])
    before = g.op("Div", [total, g.i(2, 2)])
    after = g.op("Sub", [total, before])
    pads = g.op("Concat", [g.i(0, 0), before, g.i(0, 0), after], axis=0)
    x = g.op("Pad", ["image", pads], mode="edge")
    # ---- encoder
    w1 = g.w("block1.conv1.weight").sum(axis=1, keepdims=True)  # RGB copy of a gray image
    x1 = g.selu(g.conv_bn(x, "block1.conv1", "block1.bn1", False, w_override=w1))
    x1 = g.selu(g.conv_bn(x1, "block1.conv2", "block1.bn2", False))
    x2 = g.res_block(g.op("AveragePool", [x1], kernel_shape=[2, 2], strides=[2, 2]), "block2", False)
    x3 = g.res_block(g.op("AveragePool", [x2], kernel_shape=[4, 4], strides=[4, 4]), "block3", True)
    x4 = g.res_block(g.op("AveragePool", [x3], kernel_shape=[4, 4], strides=[4, 4]), "block4", True)
    # ---- aggregation
    up = dict(mode="linear", coordinate_transformation_mode="align_corners")
    parts = [g.selu(g.conv(x1, g.w("conv1.weight")))]
    for xs, key, s in ((x2, "conv2", 2), (x3, "conv3", 8), (x4, "conv4", 32)):
        y = g.selu(g.conv(xs, g.w(f"{key}.weight")))
        parts.append(g.op("Resize", [y, "", g.c(np.array([1, 1, s, s], np.float32))], **up))
    x1234 = g.op("Concat", parts, axis=1)
    s = g.selu(g.conv(x1234, g.w("score_head.0.weight")))
    s = g.selu(g.conv(s, g.w("score_head.2.weight")))
    s = g.selu(g.conv(s, g.w("score_head.4.weight")))
    s = g.op("Sigmoid", [g.conv(s, g.w("score_head.6.weight"))])
    feats = g.l2_normalise(x1234, 1)
    # ---- crop back to H x W
    starts = g.op("Concat", [g.i(0, 0), before], axis=0)
    ends = g.op("Concat", [g.i(1, 1 << 30), g.op("Add", [before, hw])], axis=0)
    scores = g.op("Slice", [s, starts, ends, g.i(0, 1, 2, 3)], out="score_map")
    feats = g.op("Slice", [feats, starts, ends, g.i(0, 1, 2, 3)], out="feature_map")
    h_i = g.op("Gather", [hw, g.c(np.int64(0), np.int64)], axis=0)
    w_i = g.op("Gather", [hw, g.c(np.int64(1), np.int64)], axis=0)
    h_f, w_f = g.op("Cast", [h_i], to=f32), g.op("Cast", [w_i], to=f32)

    # ---- DKD: NMS with two recovery rounds (kernel 5), border, top-k
    k = 2 * RADIUS + 1
    pool = dict(kernel_shape=[k, k], strides=[1, 1], pads=[RADIUS] * 4)
    zero = g.c(np.float32(0))
    max_mask = g.op("Equal", [scores, g.op("MaxPool", [scores], **pool)])
    for _ in range(2):
        supp = g.op("Greater", [g.op("MaxPool", [g.op("Cast", [max_mask], to=f32)], **pool), zero])
        supp_scores = g.op("Where", [supp, zero, scores])
        new_max = g.op("Equal", [supp_scores, g.op("MaxPool", [supp_scores], **pool)])
        max_mask = g.op("Or", [max_mask, g.op("And", [new_max, g.op("Not", [supp])])])
    nms = g.op("Where", [max_mask, scores, zero])

    def inside(n):  # [n] float mask: 1 where RADIUS <= i < n - RADIUS
        r = g.op("Range", [g.c(np.int64(0), np.int64), n, g.c(np.int64(1), np.int64)])
        ok = g.op("And", [g.op("GreaterOrEqual", [r, g.c(np.int64(RADIUS), np.int64)]),
                          g.op("Less", [r, g.op("Sub", [n, g.c(np.int64(RADIUS), np.int64)])])])
        return g.op("Cast", [ok], to=f32)
    border = g.op("Mul", [g.op("Unsqueeze", [inside(h_i), g.i(1)]), g.op("Unsqueeze", [inside(w_i), g.i(0)])])
    nms = g.op("Mul", [nms, border])
    flat_nms = g.op("Reshape", [nms, g.i(1, -1)])
    hw_count = g.op("Mul", [h_i, w_i])
    kk = g.op("Min", ["top_k", g.op("Reshape", [hw_count, g.i(1)])])
    top_values, top_idx = g.ops("TopK", [flat_nms, kk], 2, axis=-1, largest=1, sorted=1)
    idx = g.op("Reshape", [top_idx, g.i(-1)])  # [K]
    ys = g.op("Div", [idx, w_i])
    xs = g.op("Mod", [idx, w_i])
    # soft-argmax over the 5x5 window around each maximum (all inside: the border is gone)
    dy, dx = np.meshgrid(np.arange(-RADIUS, RADIUS + 1), np.arange(-RADIUS, RADIUS + 1), indexing="ij")
    dy, dx = dy.reshape(1, -1), dx.reshape(1, -1)
    window = g.op("Add", [g.op("Mul", [g.c(dy, np.int64), w_i]), g.c(dx, np.int64)])  # [1, 25]
    flat_s = g.op("Reshape", [scores, g.i(-1)])
    patch = g.op("Gather", [flat_s, g.op("Add", [g.op("Unsqueeze", [idx, g.i(1)]), window])], axis=0)  # [K, 25]
    top = g.op("ReduceMax", [patch, g.i(1)], keepdims=1)
    e = g.op("Exp", [g.op("Div", [g.op("Sub", [patch, top]), g.c(np.float32(TEMPERATURE))])])
    grid = np.stack([dx.reshape(-1), dy.reshape(-1)], axis=1).astype(np.float32)  # [25, 2] (x, y)
    residual = g.op("Div", [g.op("MatMul", [e, g.c(grid)]), g.op("ReduceSum", [e, g.i(1)], keepdims=1)])
    xy_int = g.op("Cast", [g.op("Concat", [g.op("Unsqueeze", [xs, g.i(1)]), g.op("Unsqueeze", [ys, g.i(1)])], axis=1)], to=f32)
    kpts = g.op("Add", [xy_int, residual])  # [K, 2] pixels
    wh1 = g.op("Sub", [g.op("Concat", [g.op("Unsqueeze", [w_f, g.i(0)]), g.op("Unsqueeze", [h_f, g.i(0)])], axis=0),
                       g.c(np.float32(1))])  # [w - 1, h - 1]

    def to_grid(p):  # pixels -> [-1, 1] (aligned corners)
        return g.op("Sub", [g.op("Mul", [g.op("Div", [p, wh1]), g.c(np.float32(2))]), g.c(np.float32(1))])

    sample = dict(mode="bilinear", padding_mode="zeros", align_corners=1)
    kpt_scores = g.op("GridSample", [scores, g.op("Reshape", [to_grid(kpts), g.i(1, 1, -1, 2)])], **sample)

    # ---- SDDH descriptors
    dims = g.w("desc_head.sf_conv.weight").shape[0]
    kl = g.op("Floor", [kpts])
    lo = g.c(np.float32(0))
    hi = g.op("Sub", [wh1, g.c(np.float32(3))])  # [w - 4, h - 4]
    corner = g.op("Cast", [g.op("Max", [g.op("Min", [g.op("Sub", [kl, g.c(np.float32(1))]), hi]), lo])], to=i64)
    cx = g.op("Gather", [corner, g.c(np.int64(0), np.int64)], axis=1)
    cy = g.op("Gather", [corner, g.c(np.int64(1), np.int64)], axis=1)
    pa, pb = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")  # (row, column) of the 3x3 patch
    rel = g.op("Add", [g.op("Mul", [g.c(pa.reshape(1, -1), np.int64), w_i]), g.c(pb.reshape(1, -1), np.int64)])  # [1, 9]
    at = g.op("Add", [g.op("Unsqueeze", [g.op("Add", [g.op("Mul", [cy, w_i]), cx]), g.i(1)]), rel])  # [K, 9]
    flat_f = g.op("Reshape", [feats, g.i(dims, -1)])  # [C, H * W]
    patches = g.op("Gather", [flat_f, at], axis=1)  # [C, K, 9]
    patches = g.op("Reshape", [g.op("Transpose", [patches], perm=[1, 0, 2]), g.i(0, -1)])  # [K, C * 9]
    w0, b0 = g.w("desc_head.offset_conv.0.weight"), g.w("desc_head.offset_conv.0.bias")
    w2, b2 = g.w("desc_head.offset_conv.2.weight"), g.w("desc_head.offset_conv.2.bias")
    h = g.selu(g.op("Add", [g.op("MatMul", [patches, g.c(w0.reshape(w0.shape[0], -1).T)]), g.c(b0)]))
    off = g.op("Add", [g.op("MatMul", [h, g.c(w2.reshape(w2.shape[0], -1).T)]), g.c(b2)])  # [K, 2M]
    limit = g.op("Div", [g.op("Max", [h_f, w_f]), g.c(np.float32(4))])
    off = g.op("Clip", [off, g.op("Neg", [limit]), limit])
    off = g.op("Transpose", [g.op("Reshape", [off, g.i(0, 2, N_POS)])], perm=[0, 2, 1])  # [K, M, 2] (dx, dy)
    pos = g.op("Add", [g.op("Unsqueeze", [kpts, g.i(1)]), off])  # [K, M, 2]
    sampled = g.op("GridSample", [feats, g.op("Unsqueeze", [to_grid(pos), g.i(0)])], **sample)  # [1, C, K, M]
    sampled = g.op("Transpose", [g.op("Squeeze", [sampled, g.i(0)])], perm=[1, 2, 0])  # [K, M, C]
    wsf = g.w("desc_head.sf_conv.weight").reshape(dims, dims)
    sampled = g.selu(g.op("MatMul", [sampled, g.c(wsf.T)]))
    agg = g.w("desc_head.agg_weights")  # [M, C, D]
    desc = g.op("MatMul", [g.op("Reshape", [sampled, g.i(0, -1)]), g.c(agg.reshape(-1, agg.shape[2]))])  # [K, D]
    desc = g.l2_normalise(desc, 1)

    g.op("Unsqueeze", [kpts, g.i(0)], out="keypoints")
    g.op("Identity", [top_values], out="detection_scores")
    g.op("Reshape", [kpt_scores, g.i(1, -1)], out="scores")
    g.op("Unsqueeze", [desc, g.i(0)], out="descriptors")
    graph = helper.make_graph(
        g.nodes, "aliked_n16",
        [helper.make_tensor_value_info("image", f32, [1, 1, "height", "width"]),
         helper.make_tensor_value_info("top_k", i64, [1])],
        [helper.make_tensor_value_info("keypoints", f32, [1, "K", 2]),
         helper.make_tensor_value_info("detection_scores", f32, [1, "K"]),
         helper.make_tensor_value_info("scores", f32, [1, "K"]),
         helper.make_tensor_value_info("descriptors", f32, [1, "K", dims])],
        g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 19)], producer_name="supermvo-export")
    model.ir_version = 9
    onnx.checker.check_model(model)
    return model
