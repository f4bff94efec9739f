"""LightGlue / LighterGlue (Lindenberger et al., ICCV 2023) as an ONNX graph, from its state dict.

Inputs  `kpts0` [1, M, 2], `kpts1` [1, N, 2]: keypoints normalised as
        (kpts - size / 2) / (max(size) / 2); `desc0` [1, M, D_in], `desc1` [1, N, D_in].
Output  `log_assignment` [1, M + 1, N + 1]: the log assignment matrix of the last layer
        (dustbins in the last row and column). Mutual nearest neighbours and the
        confidence threshold are applied by the caller (supermvo's Rust matcher), so both
        stay configurable at run time.

With `adaptive=True` (the default export of `lighterglue`) the graph also has LightGlue's
adaptive width and depth, controlled by two scalar inputs:
* `min_matchability` (point pruning; 1 - width_confidence, 0.05 for the reference
  LighterGlue; negative keeps every point): after every layer but the last, keypoints whose
  matchability `sigmoid(matchability_i(x))` is not above it leave both images' sets, so later
  layers attend over fewer points;
* `depth_confidence` (early stopping; LightGlue's 0.95, the reference LighterGlue's -1 =
  off): after every layer but the last, when more than this fraction of the m + n keypoints
  have a token confidence above the layer's threshold, that layer's assignment head gives
  the output and the remaining layers run on empty sets (every layer stays in the main
  graph, where ONNX Runtime pre-packs MatMul weights; only the heads sit in `If` branches).
  With early stopping on, low-confidence points are never pruned, as in LightGlue.
Three more outputs: `kept0` [M'] and `kept1` [N'] (int64) give the original index of each
row and column of the (smaller) `log_assignment` [1, M' + 1, N' + 1], and `layers` (int64
scalar) the number of layers that ran (LightGlue's `stop`).
`heads` > 1 (LightGlue proper: 4 heads of 64 over 256 dimensions, 9 layers) splits self and
cross attention into heads as rank-4 tensors [1, heads, N, head]; LighterGlue has one head.
Each weight is one initializer shared by both images and every branch.
Implementation notes: `Wqkv`'s interleaved rows are regrouped into one MatMul giving q,
rotate_half(q), k, rotate_half(k) and v (rotate_half, a signed permutation, folded into
copies of the q and k weights: the same numbers without a reshape, gathers and two small
MatMuls); the frequency `repeat_interleave` is a constant matrix; GELU is exact (erf,
written as ONNX Runtime's Gelu fusion expects it); LayerNorm eps is 1e-5. Subnormal floats
in the attention make these graphs several times slower on x86 unless the runtime flushes
them to zero (supermvo's sessions do).
"""
import math

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


class _G:
    def __init__(self, sd, prefix):
        self.sd, self.prefix = sd, prefix
        self.nodes, self.inits, self.n = [], [], 0
        self.shared = {}

    def w(self, key):
        k = self.prefix + key
        if k not in self.sd:
            raise KeyError(f"weight '{k}' missing from the checkpoint")
        return self.sd[k].astype(np.float32)

    def c(self, arr, dtype=np.float32):
        self.n += 1
        name = f"c{self.n}"
        self.inits.append(numpy_helper.from_array(np.asarray(arr, dtype=dtype), name))
        return name

    def op(self, op, inputs, out=None, **attrs):
        self.n += 1
        out = out or f"{op.lower()}_{self.n}"
        self.nodes.append(helper.make_node(op, inputs, [out], name=f"n{self.n}_{op}", **attrs))
        return out

    def linear(self, x, key, scale=1.0):
        # one initializer per weight, shared by every use (both images, every branch)
        if (key, scale) not in self.shared:
            b = f"{key}.bias"
            self.shared[key, scale] = (self.c(self.w(f"{key}.weight").T * scale),
                                       self.c(self.w(b) * scale) if self.prefix + b in self.sd else None)
        w, b = self.shared[key, scale]
        y = self.op("MatMul", [x, w])
        return y if b is None else self.op("Add", [y, b])

    def t(self, x):  # swap the last two axes of a rank-3 tensor
        return self.op("Transpose", [x], perm=[0, 2, 1])

    def ffn(self, x, message, key):
        h = self.op("Concat", [x, message], axis=-1)
        h = self.linear(h, f"{key}.ffn.0")
        h = self.op("LayerNormalization", [h, self.c(self.w(f"{key}.ffn.1.weight")), self.c(self.w(f"{key}.ffn.1.bias"))],
                    axis=-1, epsilon=1e-5)
        # exact GELU: 0.5 x (1 + erf(x / sqrt 2))
        e = self.op("Erf", [self.op("Div", [h, self.c(np.float32(math.sqrt(2)))])])
        h = self.op("Mul", [self.op("Mul", [h, self.op("Add", [e, self.c(np.float32(1))])]), self.c(np.float32(0.5))])
        return self.op("Add", [x, self.linear(h, f"{key}.ffn.3")])


def build(sd, prefix="matcher.", n_layers=6, dim=96, name="lighterglue", adaptive=False, heads=1):
    g = _G(sd, prefix)
    head = dim // heads  # the width of one attention head
    # rotate_half as a matrix: (x0, x1, x2, x3, ...) -> (-x1, x0, -x3, x2, ...)
    rot = np.zeros((head, head), np.float32)
    for i in range(head // 2):
        rot[2 * i + 1, 2 * i] = -1.0
        rot[2 * i, 2 * i + 1] = 1.0
    rot = np.kron(np.eye(heads, dtype=np.float32), rot)  # per head, on [.., dim]
    expand = np.zeros((head // 2, dim), np.float32)  # repeat_interleave(2), then the same for every head
    for h in range(heads):
        for i in range(head // 2):
            expand[i, h * head + 2 * i] = expand[i, h * head + 2 * i + 1] = 1.0
    expand_c = g.c(expand)
    wr = g.c(g.w("posenc.Wr.weight").T)
    inv_sqrt = np.float32(1 / math.sqrt(head))
    f32, i64 = TensorProto.FLOAT, TensorProto.INT64

    def encoding(k):  # [1, N, dim]: with several heads, every head gets the same encoding
        proj = g.op("MatMul", [k, wr])
        return (g.op("MatMul", [g.op("Cos", [proj]), expand_c]), g.op("MatMul", [g.op("Sin", [proj]), expand_c]))

    def split(t):  # [1, N, dim] -> [1, heads, N, head]
        return g.op("Transpose", [g.op("Reshape", [t, g.c(np.array([1, -1, heads, head], np.int64), np.int64)])], perm=[0, 2, 1, 3])

    def merge(t):  # [1, heads, N, head] -> [1, N, dim]
        return g.op("Reshape", [g.op("Transpose", [t], perm=[0, 2, 1, 3]), g.c(np.array([1, -1, dim], np.int64), np.int64)])

    def t4(t):  # swap the last two axes of a rank-4 tensor
        return g.op("Transpose", [t], perm=[0, 1, 3, 2])

    def transformer_heads(layer, x, enc):
        """LightGlue with several attention heads (rank-4 tensors [1, heads, N, head])."""
        x = list(x)
        key = f"transformers.{layer}.self_attn"
        for s in range(2):
            q, q_rot, k, k_rot, v = split_qkv(x[s], key)
            cos, sin = enc[s]  # [1, N, dim]: one head's encoding repeated for every head
            q = split(g.op("Add", [g.op("Mul", [q, cos]), g.op("Mul", [q_rot, sin])]))
            k = split(g.op("Add", [g.op("Mul", [k, cos]), g.op("Mul", [k_rot, sin])]))
            v = split(v)
            att = g.op("Softmax", [g.op("Mul", [g.op("MatMul", [q, t4(k)]), g.c(inv_sqrt)])], axis=-1)
            msg = g.linear(merge(g.op("MatMul", [att, v])), f"{key}.out_proj")
            x[s] = g.ffn(x[s], msg, key)
        key = f"transformers.{layer}.cross_attn"
        s4 = float(head) ** -0.25
        qk0, qk1 = split(g.linear(x[0], f"{key}.to_qk", s4)), split(g.linear(x[1], f"{key}.to_qk", s4))
        v0, v1 = split(g.linear(x[0], f"{key}.to_v")), split(g.linear(x[1], f"{key}.to_v"))
        sim = g.op("MatMul", [qk0, t4(qk1)])
        m0 = merge(g.op("MatMul", [g.op("Softmax", [sim], axis=-1), v1]))
        m1 = merge(g.op("MatMul", [g.op("Softmax", [t4(sim)], axis=-1), v0]))
        return [g.ffn(x[0], g.linear(m0, f"{key}.to_out"), key), g.ffn(x[1], g.linear(m1, f"{key}.to_out"), key)]

    qkv_weights = {}

    def split_qkv(x, key):
        """q, rotate_half(q), k, rotate_half(k), v from one MatMul: `Wqkv`'s interleaved rows
        regrouped, and rotate_half (a signed permutation) folded into copies of the q and k
        weights, so the products are the same numbers without a reshape, gathers and two
        small MatMuls."""
        if key not in qkv_weights:
            w, b = g.w(f"{key}.Wqkv.weight"), g.w(f"{key}.Wqkv.bias")  # [3 dim, dim], rows d * 3 + j
            parts_w, parts_b = [], []
            for j, with_rot in ((0, True), (1, True), (2, False)):
                wj, bj = w[j::3].T, b[j::3]
                parts_w.append(wj)
                parts_b.append(bj)
                if with_rot:
                    parts_w.append(wj @ rot)
                    parts_b.append(bj @ rot)
            qkv_weights[key] = (g.c(np.concatenate(parts_w, axis=1)), g.c(np.concatenate(parts_b)))
        w, b = qkv_weights[key]
        y = g.op("Add", [g.op("MatMul", [x, w]), b])
        outs = [f"{y}_{i}" for i in range(5)]
        g.n += 1
        g.nodes.append(helper.make_node("Split", [y, g.c(np.full(5, dim, np.int64), np.int64)], outs, name=f"n{g.n}_Split", axis=-1))
        return outs

    def transformer(layer, x, enc):
        if heads > 1:
            return transformer_heads(layer, x, enc)
        x = list(x)
        key = f"transformers.{layer}.self_attn"
        for s in range(2):
            q, q_rot, k, k_rot, v = split_qkv(x[s], key)
            cos, sin = enc[s]
            q = g.op("Add", [g.op("Mul", [q, cos]), g.op("Mul", [q_rot, sin])])
            k = g.op("Add", [g.op("Mul", [k, cos]), g.op("Mul", [k_rot, sin])])
            att = g.op("Softmax", [g.op("Mul", [g.op("MatMul", [q, g.t(k)]), g.c(inv_sqrt)])], axis=-1)
            msg = g.linear(g.op("MatMul", [att, v]), f"{key}.out_proj")
            x[s] = g.ffn(x[s], msg, key)
        key = f"transformers.{layer}.cross_attn"
        s4 = float(head) ** -0.25
        qk0, qk1 = g.linear(x[0], f"{key}.to_qk", s4), g.linear(x[1], f"{key}.to_qk", s4)
        v0, v1 = g.linear(x[0], f"{key}.to_v"), g.linear(x[1], f"{key}.to_v")
        sim = g.op("MatMul", [qk0, g.t(qk1)])
        m0 = g.op("MatMul", [g.op("Softmax", [sim], axis=-1), v1])
        m1 = g.op("MatMul", [g.op("Softmax", [g.t(sim)], axis=-1), v0])
        return [g.ffn(x[0], g.linear(m0, f"{key}.to_out"), key), g.ffn(x[1], g.linear(m1, f"{key}.to_out"), key)]

    def logsigmoid(v):
        return g.op("Neg", [g.op("Softplus", [g.op("Neg", [v])])])

    def assignment(layer, x):
        key = f"log_assignment.{layer}"
        s4 = float(dim) ** -0.25
        md0, md1 = g.linear(x[0], f"{key}.final_proj", s4), g.linear(x[1], f"{key}.final_proj", s4)
        sim = g.op("MatMul", [md0, g.t(md1)])
        z0, z1 = g.linear(x[0], f"{key}.matchability"), g.linear(x[1], f"{key}.matchability")
        core = g.op("Add", [g.op("Add", [g.op("LogSoftmax", [sim], axis=-1), g.t(g.op("LogSoftmax", [g.t(sim)], axis=-1))]),
                            g.op("Add", [logsigmoid(z0), g.t(logsigmoid(z1))])])
        top = g.op("Concat", [core, logsigmoid(g.op("Neg", [z0]))], axis=2)
        bottom = g.op("Concat", [g.t(logsigmoid(g.op("Neg", [z1]))), g.c(np.zeros((1, 1, 1), np.float32))], axis=2)
        return g.op("Concat", [top, bottom], axis=1)

    def confidence_threshold(layer):  # LightGlue's per-layer token-confidence threshold
        return np.float32(np.clip(0.8 + 0.1 * np.exp(-4.0 * layer / n_layers), 0, 1))

    def branch(build_outputs, graph_name, types):
        """A subgraph for an If node: the nodes `build_outputs` adds, outputs wrapped in Identity."""
        saved, g.nodes = g.nodes, []
        outs = [g.op("Identity", [o]) for o in build_outputs()]
        nodes, g.nodes = g.nodes, saved
        return helper.make_graph(nodes, graph_name, [], [helper.make_tensor_value_info(o, t, None) for o, t in zip(outs, types)])

    def select(cond, then_outputs, else_outputs, label):
        """If(cond) between two lists of tensors (only the chosen branch's nodes run)."""
        types = [f32, i64, i64, i64]
        then_g = branch(then_outputs, f"{label}_then", types)
        else_g = branch(else_outputs, f"{label}_else", types)
        g.n += 1
        outs = [f"{label}_la", f"{label}_k0", f"{label}_k1", f"{label}_layers"]
        g.nodes.append(helper.make_node("If", [cond], outs, name=f"n{g.n}_If", then_branch=then_g, else_branch=else_g))
        return outs

    enc = [encoding("kpts0"), encoding("kpts1")]
    x = [g.linear("desc0", "input_proj"), g.linear("desc1", "input_proj")]
    if not adaptive:
        for layer in range(n_layers):
            x = transformer(layer, x, enc)
        result = [assignment(n_layers - 1, x)]
    else:
        # Every layer stays in the main graph (ONNX Runtime pre-packs the weights of the main
        # graph's MatMuls, not those inside If branches: outputs would differ in the last
        # digits and run slower). Early stopping after layer i records layer i's assignment (an
        # If that runs the head only then) and prunes every point, so the remaining layers run
        # on empty sets; the output is the recorded assignment.
        def arange(k):
            count = g.op("Gather", [g.op("Shape", [k]), g.c(np.int64(1), np.int64)], axis=0)
            return g.op("Range", [g.c(np.int64(0), np.int64), count, g.c(np.int64(1), np.int64)]), count
        (k0, c0), (k1, c1) = arange("kpts0"), arange("kpts1")
        kept = [k0, k1]
        total = g.op("Cast", [g.op("Add", [c0, c1])], to=f32)
        flat = g.c(np.array([-1], np.int64), np.int64)
        depth_on = g.op("Greater", ["depth_confidence", g.c(np.float32(0))])
        stopped = g.c(np.array(False), np.bool_)
        recorded = [g.c(np.zeros((1, 1, 1), np.float32)), g.c(np.zeros(0, np.int64), np.int64), g.c(np.zeros(0, np.int64), np.int64),
                    g.c(np.int64(n_layers), np.int64)]
        for layer in range(n_layers):
            x = transformer(layer, x, enc)
            if layer == n_layers - 1:
                break
            thr = g.c(confidence_threshold(layer))
            token = [g.op("Reshape", [g.op("Sigmoid", [g.linear(x[s], f"token_confidence.{layer}.token.0")]), flat]) for s in range(2)]
            # stop when 1 - (points below the threshold) / (m + n) > depth_confidence (> 0)
            low = g.op("ReduceSum", [g.op("Cast", [g.op("Less", [g.op("Concat", token, axis=0), thr])], to=f32)], keepdims=0)
            ratio = g.op("Sub", [g.c(np.float32(1)), g.op("Div", [low, total])])
            stop = g.op("And", [g.op("Not", [stopped]), g.op("And", [depth_on, g.op("Greater", [ratio, "depth_confidence"])])])
            prev = list(recorded)
            recorded = select(stop, lambda layer=layer, x=x, kept=list(kept): [assignment(layer, x), kept[0], kept[1],
                                                                                  g.c(np.int64(layer + 1), np.int64)],
                              lambda prev=prev: prev, f"stop_after_layer_{layer}")
            stopped = g.op("Or", [stopped, stop])
            go_on = g.op("Not", [stopped])
            # adaptive width: keep points that may still match or whose confidence is low
            new_x, new_enc = list(x), list(enc)
            for s in range(2):
                score = g.op("Reshape", [g.op("Sigmoid", [g.linear(x[s], f"log_assignment.{layer}.matchability")]), flat])
                keep = g.op("Or", [g.op("Greater", [score, "min_matchability"]),
                                   g.op("And", [g.op("LessOrEqual", [token[s], thr]), depth_on])])
                idx = g.op("Reshape", [g.op("NonZero", [g.op("And", [keep, go_on])]), flat])
                new_x[s] = g.op("Gather", [x[s], idx], axis=1)
                new_enc[s] = tuple(g.op("Gather", [e, idx], axis=1) for e in enc[s])
                kept[s] = g.op("Gather", [kept[s], idx], axis=0)
            x, enc = new_x, new_enc
        last = [assignment(n_layers - 1, x), kept[0], kept[1], g.c(np.int64(n_layers), np.int64)]  # empty sets once stopped
        result = select(stopped, lambda: recorded, lambda: last, "output")
    d_in = g.w("input_proj.weight").shape[1]
    inputs = [helper.make_tensor_value_info("kpts0", f32, [1, "M", 2]), helper.make_tensor_value_info("kpts1", f32, [1, "N", 2]),
              helper.make_tensor_value_info("desc0", f32, [1, "M", d_in]), helper.make_tensor_value_info("desc1", f32, [1, "N", d_in])]
    outputs = [helper.make_tensor_value_info("log_assignment", f32, [1, "M1", "N1"])]
    for value, out in zip(result, ["log_assignment", "kept0", "kept1", "layers"]):
        g.op("Identity", [value], out=out)
    if adaptive:
        inputs += [helper.make_tensor_value_info("min_matchability", f32, []),
                   helper.make_tensor_value_info("depth_confidence", f32, [])]
        outputs += [helper.make_tensor_value_info("kept0", i64, ["K0"]), helper.make_tensor_value_info("kept1", i64, ["K1"]),
                    helper.make_tensor_value_info("layers", i64, [])]
    graph = helper.make_graph(g.nodes, name, inputs, outputs, g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="supermvo-export")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model
