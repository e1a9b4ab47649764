"""Compute a 1 x 1 conv head that Slices split between custom ops as MatMuls on NCHW, at export.

ONNX Runtime runs a Conv in its blocked NCHWc layout and reorders the output back to NCHW for
any op outside that layout; a channel Slice of it is then one more copy. AFN's full-scale head
(16 features -> 49 kernel logits for SoftmaxKernelApply + 1 fusion weight) cost, at 720p on 2
cores, 26 ms of conv, 39 ms to reorder its 50 channels and 25 ms for the Split.

`matmul_heads` rewrites such a conv y = W x + b (W: (T, C), x: (N, C, H, W)), read only by
constant channel Slices, one part per Slice: a part wider than the input (T_k > C) becomes

    xa = Reshape(Concat(x, ones (N, 1, H, W)), (N, C + 1, H*W))   (the bias row)
    y_k = Reshape(MatMul([W_k | b_k], xa), (N, T_k, H, W))

(ORT reorders the C input channels instead of the T_k outputs, and the bias rides in the GEMM:
a separate Add over the 49 x H x W output cost more than the MatMul), a narrower part a conv
over its rows of W (its own small reorder). Each output element is the same sum in the same
order as the conv's: ONNX Runtime's outputs were bit-identical. A conv that a custom op reads
whole is left alone: there the MatMul (with its input reorder) measured no faster than the
conv and its output reorder (benchmarks/README.md).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .conv_widths import (
    CHANNEL_AXES,
    Graph,
    auto_pad,
    constant_channels,
    drop_unread_initializers,
    ints_attribute,
    is_standard,
)

# doc_string of the MatMul nodes made here: the last row of their right operand is ones, so
# the last column of their weights is the conv's bias (benchmarks/flops.py does not count it)
BIAS_ROW_DOC = "rtdenoise: 1x1 Conv as MatMul; the last input row is ones, its weights the bias"


def _pointwise(g: Graph, conv: onnx.NodeProto) -> bool:
    """A plain 1 x 1 conv, stride 1, no padding."""
    if not g.plain_conv(conv):
        return False
    weight = g.inits[conv.input[1]]
    return (
        len(weight.dims) == 4
        and tuple(weight.dims[2:]) == (1, 1)
        and all(s == 1 for s in ints_attribute(conv, "strides") or [1])
        and all(p == 0 for p in ints_attribute(conv, "pads") or [0])
        and auto_pad(conv) in (b"NOTSET", b"VALID")
    )


def _const(g: Graph, name: str) -> np.ndarray | None:
    init = g.inits.get(name)
    return None if init is None else numpy_helper.to_array(init)


def _channel_range(g: Graph, node: onnx.NodeProto, channels: int) -> tuple[int, int] | None:
    """(start, stop) of a Slice that takes a constant step-1 range of channels, else None."""
    if node.op_type != "Slice" or not is_standard(node) or len(node.input) < 3:
        return None
    starts, ends = _const(g, node.input[1]), _const(g, node.input[2])
    axes = _const(g, node.input[3]) if len(node.input) > 3 and node.input[3] else np.array([0])
    steps = _const(g, node.input[4]) if len(node.input) > 4 and node.input[4] else np.array([1])
    if any(v is None or v.size != 1 for v in (starts, ends, axes, steps)):
        return None
    if int(axes[0]) not in CHANNEL_AXES or int(steps[0]) != 1:
        return None
    start, stop = int(starts[0]), int(ends[0])
    start = max(0, min(channels, start + channels if start < 0 else start))
    stop = max(0, min(channels, stop + channels if stop < 0 else stop))
    return (start, stop) if stop > start else None


def _slices(g: Graph, conv: onnx.NodeProto, channels: int) -> list | None:
    """[(output name, start, stop, Slice node)] of the conv's output, or None unless every
    reader is a constant channel Slice."""
    out = conv.output[0]
    if out in g.outputs or not g.consumers[out]:
        return None
    parts = []
    for reader in g.consumers[out]:
        found = _channel_range(g, reader, channels)
        if found is None or reader.input[0] != out:
            return None
        parts.append((reader.output[0], *found, reader))
    return parts


def matmul_heads(proto: onnx.ModelProto) -> list[tuple[str, int, int]]:
    """Rewrite, in place, every 1 x 1 conv of the main graph that only constant channel Slices
    read, one of them wider than the conv's input (module docstring); returns (conv name, in
    channels, out channels)."""
    g = Graph(proto)
    graph = proto.graph
    done = []
    for conv in list(graph.node):
        if not _pointwise(g, conv):
            continue
        weight = numpy_helper.to_array(g.inits[conv.input[1]])
        t, c = weight.shape[:2]
        parts = _slices(g, conv, t) if t > c else None
        if not parts or all(stop - start <= c for _, start, stop, _ in parts):
            continue
        has_bias = len(conv.input) > 2 and conv.input[2]
        bias = numpy_helper.to_array(g.inits[conv.input[2]]) if has_bias else np.zeros(t)
        bias = bias.astype(weight.dtype)
        nodes = _augmented_input(graph, conv, c)
        for k, (name, start, stop, _) in enumerate(parts):
            rows = weight[start:stop], bias[start:stop]
            make = _matmul_part if stop - start > c else _conv_part
            nodes += make(graph, conv, f"{conv.name or conv.output[0]}_part{k}", name, *rows)
        at = list(graph.node).index(conv)
        removed = {id(conv), *(id(s) for *_, s in parts)}
        kept = [n for n in graph.node if id(n) not in removed]
        kept[at:at] = nodes
        del graph.node[:]
        graph.node.extend(kept)
        drop_unread_initializers(
            graph, {i for n in (conv, *(s for *_, s in parts)) for i in n.input}
        )
        g.forget_shapes({conv.output[0]})
        done.append((conv.name, c, t))
        g = Graph(proto)
    return done


def _matmul_part(graph, conv, base: str, out: str, weight: np.ndarray, bias: np.ndarray) -> list:
    """out = Reshape(MatMul([W | b], xa), (N, T, H, W)) for a wide part (T > C)."""
    head = conv.name or conv.output[0]
    augmented = np.concatenate([weight[:, :, 0, 0], bias[:, None]], axis=1)
    graph.initializer.append(numpy_helper.from_array(augmented, f"{base}_weight"))
    graph.initializer.append(numpy_helper.from_array(np.array([len(bias)]), f"{base}_size"))
    return [
        helper.make_node(
            "MatMul",
            [f"{base}_weight", f"{head}_xa"],
            [f"{base}_flat"],
            name=base,
            doc_string=BIAS_ROW_DOC,
        ),
        helper.make_node(
            "Concat",
            [f"{head}_ones_n", f"{base}_size", f"{head}_ones_hw"],
            [f"{base}_shape"],
            axis=0,
            name=f"{base}_shape",
        ),
        helper.make_node("Reshape", [f"{base}_flat", f"{base}_shape"], [out], name=f"{base}_nchw"),
    ]


def _conv_part(graph, conv, base: str, out: str, weight: np.ndarray, bias: np.ndarray) -> list:
    """out = the conv over its rows of W (a narrow part: its own output, no Slice copy)."""
    graph.initializer.append(numpy_helper.from_array(weight, f"{base}_weight"))
    graph.initializer.append(numpy_helper.from_array(bias, f"{base}_bias"))
    attrs = {a.name: helper.get_attribute_value(a) for a in conv.attribute}
    return [
        helper.make_node(
            "Conv", [conv.input[0], f"{base}_weight", f"{base}_bias"], [out], name=base, **attrs
        )
    ]


def _augmented_input(graph: onnx.GraphProto, conv: onnx.NodeProto, channels: int) -> list:
    """Nodes making `<conv>_xa` = [x; ones] as (N, C + 1, H*W) from the conv's input x (N, C,
    H, W), and on the way the shape pieces `<conv>_ones_n` (N) and `<conv>_ones_hw` (H, W)."""
    x, base = conv.input[0], conv.name or conv.output[0]
    flat = f"{base}_flat_shape"
    graph.initializer.append(numpy_helper.from_array(np.array([0, channels + 1, -1]), flat))
    return [
        *constant_channels(graph, x, 1, 1.0, f"{base}_ones"),
        helper.make_node("Concat", [x, f"{base}_ones"], [f"{base}_x1"], axis=1, name=f"{base}_x1"),
        helper.make_node("Reshape", [f"{base}_x1", flat], [f"{base}_xa"], name=f"{base}_xa"),
    ]
