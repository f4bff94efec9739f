"""SuperPoint (DeTone, Malisiewicz and Rabinovich, CVPRW 2018) as an ONNX graph, from the
state dict of the official `superpoint_v1.pth` (MagicLeap's file layout: `conv1a` ...
`conv4b`, detector head `convPa`/`convPb`, descriptor head `convDa`/`convDb`).

Input   `image` [1, 1, H, W]: grayscale in [0, 1], H and W multiples of 8.
Outputs `scores_logits` [1, 65, H/8, W/8]: the detector's logits (64 cell positions and
        the "no keypoint" bin; softmax, depth-to-space, NMS and top-k are the caller's);
        `descriptors` [1, 256, H/8, W/8]: the coarse descriptors, L2-normalised per cell.
"""
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

# (name, in, out, kernel) in order; 2x2 max pooling after conv1b, conv2b and conv3b
ENCODER = [("conv1a", 3), ("conv1b", 3), ("conv2a", 3), ("conv2b", 3), ("conv3a", 3), ("conv3b", 3), ("conv4a", 3), ("conv4b", 3)]
POOL_AFTER = {"conv1b", "conv2b", "conv3b"}


def build(sd, prefix="", name="superpoint"):
    nodes, inits = [], []
    n = [0]

    def w(key):
        k = prefix + key
        if k not in sd:
            raise KeyError(f"weight '{k}' missing from the checkpoint (is it SuperPoint v1?)")
        return np.asarray(sd[k], np.float32)

    def node(op, inputs, out=None, **attrs):
        n[0] += 1
        out = out or f"{op.lower()}_{n[0]}"
        nodes.append(helper.make_node(op, inputs, [out], name=f"n{n[0]}_{op}", **attrs))
        return out

    def const(arr, dtype=np.float32):
        n[0] += 1
        cname = f"c{n[0]}"
        inits.append(numpy_helper.from_array(np.asarray(arr, dtype), cname))
        return cname

    def conv(x, key, relu, out=None):
        weight = w(f"{key}.weight")
        k = weight.shape[-1]
        y = node("Conv", [x, const(weight), const(w(f"{key}.bias"))], kernel_shape=[k, k], pads=[k // 2] * 4)
        return node("Relu", [y], out=out) if relu else (node("Identity", [y], out=out) if out else y)

    x = "image"
    for key, _k in ENCODER:
        x = conv(x, key, relu=True)
        if key in POOL_AFTER:
            x = node("MaxPool", [x], kernel_shape=[2, 2], strides=[2, 2])
    conv(conv(x, "convPa", relu=True), "convPb", relu=False, out="scores_logits")
    d = conv(conv(x, "convDa", relu=True), "convDb", relu=False)
    norm = node("ReduceL2", [d, const(np.array([1], np.int64), np.int64)], keepdims=1)
    node("Div", [d, node("Max", [norm, const(np.float32(1e-12))])], out="descriptors")
    f32 = TensorProto.FLOAT
    graph = helper.make_graph(
        nodes, name, [helper.make_tensor_value_info("image", f32, [1, 1, "H", "W"])],
        [helper.make_tensor_value_info("scores_logits", f32, [1, 65, "h", "w"]),
         helper.make_tensor_value_info("descriptors", f32, [1, w("convDb.weight").shape[0], "h", "w"])],
        inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], producer_name="supermvo-export")
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def shapes(descriptor_dim=256):
    """The official state dict's keys and shapes (for random-weight tests)."""
    c = {"conv1a": (64, 1), "conv1b": (64, 64), "conv2a": (64, 64), "conv2b": (64, 64), "conv3a": (128, 64),
         "conv3b": (128, 128), "conv4a": (128, 128), "conv4b": (128, 128), "convPa": (256, 128), "convDa": (256, 128)}
    out = {}
    for key, (o, i) in c.items():
        out[f"{key}.weight"], out[f"{key}.bias"] = (o, i, 3, 3), (o,)
    out["convPb.weight"], out["convPb.bias"] = (65, 256, 1, 1), (65,)
    out["convDb.weight"], out["convDb.bias"] = (descriptor_dim, 256, 1, 1), (descriptor_dim,)
    return out
