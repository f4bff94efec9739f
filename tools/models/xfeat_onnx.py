"""XFeat backbone (Potje et al., CVPR 2024) as an ONNX graph, built from its state dict.

Input  `image`: [B, 1, H, W] float32 grayscale (any scale: the graph instance-normalises),
       H and W multiples of 32.
Outputs `descriptors` [B, 64, H/8, W/8] (not normalised), `keypoint_logits`
       [B, 65, H/8, W/8] (64 cells of the 8x8 block + dustbin), `reliability` [B, 1, H/8, W/8].

Batch norms (affine=False, eps 1e-5) are folded into the preceding convolutions.
"""
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

BN_EPS = 1e-5

# (name, in, out, kernel, stride, padding) of each BasicLayer (conv -> BN -> ReLU)
BLOCKS = {
    "block1": [(1, 4, 3, 1, 1), (4, 8, 3, 2, 1), (8, 8, 3, 1, 1), (8, 24, 3, 2, 1)],
    "block2": [(24, 24, 3, 1, 1), (24, 24, 3, 1, 1)],
    "block3": [(24, 64, 3, 2, 1), (64, 64, 3, 1, 1), (64, 64, 1, 1, 0)],
    "block4": [(64, 64, 3, 2, 1), (64, 64, 3, 1, 1), (64, 64, 3, 1, 1)],
    "block5": [(64, 128, 3, 2, 1), (128, 128, 3, 1, 1), (128, 128, 3, 1, 1), (128, 64, 1, 1, 0)],
    "block_fusion": [(64, 64, 3, 1, 1), (64, 64, 3, 1, 1)],
    "heatmap_head": [(64, 64, 1, 1, 0), (64, 64, 1, 1, 0)],
    "keypoint_head": [(64, 64, 1, 1, 0), (64, 64, 1, 1, 0), (64, 64, 1, 1, 0)],
}


class _Graph:
    def __init__(self, sd, prefix=""):
        self.sd = sd
        self.prefix = prefix
        self.nodes = []
        self.inits = []
        self.n = 0

    def w(self, key):
        k = self.prefix + key
        if k not in self.sd:
            raise KeyError(f"weight '{k}' missing from the checkpoint")
        return self.sd[k].astype(np.float32)

    def const(self, name, arr):
        self.inits.append(numpy_helper.from_array(np.asarray(arr), name))
        return name

    def node(self, op, inputs, **attrs):
        self.n += 1
        out = f"{op.lower()}_{self.n}"
        self.nodes.append(helper.make_node(op, inputs, [out], name=out, **attrs))
        return out

    def conv(self, x, weight, bias, k, stride, pad):
        wn = self.const(f"w{self.n}_{len(self.inits)}", weight)
        bn = self.const(f"b{self.n}_{len(self.inits)}", bias)
        return self.node("Conv", [x, wn, bn], kernel_shape=[k, k], strides=[stride, stride], pads=[pad] * 4)

    def basic(self, x, key, k, stride, pad):
        w = self.w(f"{key}.layer.0.weight")
        mean = self.w(f"{key}.layer.1.running_mean")
        var = self.w(f"{key}.layer.1.running_var")
        inv = 1.0 / np.sqrt(var + BN_EPS)
        wf = (w * inv[:, None, None, None]).astype(np.float32)
        bf = (-mean * inv).astype(np.float32)
        return self.node("Relu", [self.conv(x, wf, bf, k, stride, pad)])

    def block(self, x, name):
        for i, (_cin, _cout, k, s, p) in enumerate(BLOCKS[name]):
            x = self.basic(x, f"{name}.{i}", k, s, p)
        return x


def build(sd, prefix=""):
    """Returns the ONNX model of XFeat's backbone; `prefix` selects keys inside a larger dict."""
    g = _Graph(sd, prefix)
    x = g.node("InstanceNormalization", ["image", g.const("in_scale", np.ones(1, np.float32)),
                                          g.const("in_bias", np.zeros(1, np.float32))], epsilon=1e-5)
    skip = g.node("AveragePool", [x], kernel_shape=[4, 4], strides=[4, 4])
    skip = g.conv(skip, g.w("skip1.1.weight"), g.w("skip1.1.bias"), 1, 1, 0)
    x1 = g.block(x, "block1")
    x2 = g.block(g.node("Add", [x1, skip]), "block2")
    x3 = g.block(x2, "block3")
    x4 = g.block(x3, "block4")
    x5 = g.block(x4, "block5")
    size3 = g.node("Shape", [x3])
    up = dict(mode="linear", coordinate_transformation_mode="half_pixel")
    x4u = g.node("Resize", [x4, "", "", size3], **up)
    x5u = g.node("Resize", [x5, "", "", size3], **up)
    fused = g.node("Add", [g.node("Add", [x3, x4u]), x5u])
    f = g.block(fused, "block_fusion")
    feats = g.conv(f, g.w("block_fusion.2.weight"), g.w("block_fusion.2.bias"), 1, 1, 0)
    h = g.block(feats, "heatmap_head")
    h = g.conv(h, g.w("heatmap_head.2.weight"), g.w("heatmap_head.2.bias"), 1, 1, 0)
    heat = g.node("Sigmoid", [h])
    k = g.node("SpaceToDepth", [x], blocksize=8)
    k = g.block(k, "keypoint_head")
    kl = g.conv(k, g.w("keypoint_head.3.weight"), g.w("keypoint_head.3.bias"), 1, 1, 0)
    g.nodes.append(helper.make_node("Identity", [feats], ["descriptors"]))
    g.nodes.append(helper.make_node("Identity", [kl], ["keypoint_logits"]))
    g.nodes.append(helper.make_node("Identity", [heat], ["reliability"]))
    f32 = TensorProto.FLOAT
    graph = helper.make_graph(
        g.nodes, "xfeat",
        [helper.make_tensor_value_info("image", f32, ["batch", 1, "height", "width"])],
        [helper.make_tensor_value_info("descriptors", f32, ["batch", 64, "height8", "width8"]),
         helper.make_tensor_value_info("keypoint_logits", f32, ["batch", 65, "height8", "width8"]),
         helper.make_tensor_value_info("reliability", f32, ["batch", 1, "height8", "width8"])],
        g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="supermvo-export")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model
