"""LightGlue / LighterGlue (Lindenberger et al., ICCV 2023) as an ONNX graph, from its state dict.

Inputs  `kpts0` [1, M, 2], `kpts1` [1, N, 2]: keypoints normalised as
        (kpts - size / 2) / (max(size) / 2); `desc0` [1, M, D_in], `desc1` [1, N, D_in].
Output  `log_assignment` [1, M + 1, N + 1]: the log assignment matrix of the last layer
        (dustbins in the last row and column). Mutual nearest neighbours and the
        confidence threshold are applied by the caller (supermvo's Rust matcher), so both
        stay configurable at run time.

No early stopping or point pruning: the graph always runs `n_layers` layers.
Implementation notes: the interleaved q/k/v split of `Wqkv` is a reshape to [.., D, 3];
`rotate_half` and the frequency `repeat_interleave` are constant matrices; GELU is exact
(erf); LayerNorm eps is 1e-5.
"""
import math

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


class _G:
    def __init__(self, sd, prefix):
        self.sd, self.prefix = sd, prefix
        self.nodes, self.inits, self.n = [], [], 0

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
        w = self.w(f"{key}.weight").T * scale
        y = self.op("MatMul", [x, self.c(w)])
        b = f"{key}.bias"
        if self.prefix + b in self.sd:
            y = self.op("Add", [y, self.c(self.w(b) * scale)])
        return y

    def t(self, x):  # swap the last two axes of a rank-3 tensor
        return self.op("Transpose", [x], perm=[0, 2, 1])

    def ffn(self, x, message, key):
        h = self.op("Concat", [x, message], axis=-1)
        h = self.linear(h, f"{key}.ffn.0")
        h = self.op("LayerNormalization", [h, self.c(self.w(f"{key}.ffn.1.weight")), self.c(self.w(f"{key}.ffn.1.bias"))],
                    axis=-1, epsilon=1e-5)
        # exact GELU: 0.5 x (1 + erf(x / sqrt 2))
        e = self.op("Erf", [self.op("Mul", [h, self.c(np.float32(1 / math.sqrt(2)))])])
        h = self.op("Mul", [self.op("Mul", [h, self.op("Add", [e, self.c(np.float32(1))])]), self.c(np.float32(0.5))])
        return self.op("Add", [x, self.linear(h, f"{key}.ffn.3")])


def build(sd, prefix="matcher.", n_layers=6, dim=96, name="lighterglue"):
    g = _G(sd, prefix)
    head = dim  # one head
    # rotate_half as a matrix: (x0, x1, x2, x3, ...) -> (-x1, x0, -x3, x2, ...)
    rot = np.zeros((dim, dim), np.float32)
    for i in range(dim // 2):
        rot[2 * i + 1, 2 * i] = -1.0
        rot[2 * i, 2 * i + 1] = 1.0
    rot_c = g.c(rot)
    expand = np.zeros((head // 2, head), np.float32)
    for i in range(head // 2):
        expand[i, 2 * i] = expand[i, 2 * i + 1] = 1.0
    expand_c = g.c(expand)
    wr = g.c(g.w("posenc.Wr.weight").T)

    def encoding(k):
        proj = g.op("MatMul", [k, wr])
        return (g.op("MatMul", [g.op("Cos", [proj]), expand_c]), g.op("MatMul", [g.op("Sin", [proj]), expand_c]))

    enc = [encoding("kpts0"), encoding("kpts1")]
    x = [g.linear("desc0", "input_proj"), g.linear("desc1", "input_proj")]
    shape_qkv = g.c(np.array([1, -1, dim, 3], np.int64), np.int64)
    inv_sqrt = np.float32(1 / math.sqrt(head))
    for layer in range(n_layers):
        key = f"transformers.{layer}.self_attn"
        for s in range(2):
            qkv = g.op("Reshape", [g.linear(x[s], f"{key}.Wqkv"), shape_qkv])
            q, k, v = (g.op("Gather", [qkv, g.c(np.int64(j), np.int64)], axis=3) for j in range(3))
            cos, sin = enc[s]
            q = g.op("Add", [g.op("Mul", [q, cos]), g.op("Mul", [g.op("MatMul", [q, rot_c]), sin])])
            k = g.op("Add", [g.op("Mul", [k, cos]), g.op("Mul", [g.op("MatMul", [k, rot_c]), sin])])
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
        x = [g.ffn(x[0], g.linear(m0, f"{key}.to_out"), key), g.ffn(x[1], g.linear(m1, f"{key}.to_out"), key)]
    key = f"log_assignment.{n_layers - 1}"
    s4 = float(dim) ** -0.25
    md0, md1 = g.linear(x[0], f"{key}.final_proj", s4), g.linear(x[1], f"{key}.final_proj", s4)
    sim = g.op("MatMul", [md0, g.t(md1)])
    z0, z1 = g.linear(x[0], f"{key}.matchability"), g.linear(x[1], f"{key}.matchability")

    def logsigmoid(v):
        return g.op("Neg", [g.op("Softplus", [g.op("Neg", [v])])])

    core = g.op("Add", [g.op("Add", [g.op("LogSoftmax", [sim], axis=-1), g.t(g.op("LogSoftmax", [g.t(sim)], axis=-1))]),
                        g.op("Add", [logsigmoid(z0), g.t(logsigmoid(z1))])])
    top = g.op("Concat", [core, logsigmoid(g.op("Neg", [z0]))], axis=2)
    bottom = g.op("Concat", [g.t(logsigmoid(g.op("Neg", [z1]))), g.c(np.zeros((1, 1, 1), np.float32))], axis=2)
    g.op("Concat", [top, bottom], out="log_assignment", axis=1)
    f32 = TensorProto.FLOAT
    d_in = g.w("input_proj.weight").shape[1]
    graph = helper.make_graph(
        g.nodes, name,
        [helper.make_tensor_value_info("kpts0", f32, [1, "M", 2]), helper.make_tensor_value_info("kpts1", f32, [1, "N", 2]),
         helper.make_tensor_value_info("desc0", f32, [1, "M", d_in]), helper.make_tensor_value_info("desc1", f32, [1, "N", d_in])],
        [helper.make_tensor_value_info("log_assignment", f32, [1, "M1", "N1"])],
        g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="supermvo-export")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model
