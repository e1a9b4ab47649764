"""Zero-pad conv channel counts to a multiple of 8 at export, so that ONNX Runtime's CPU convs
take their blocked (NCHWc) layout, and keep it through the network.

ORT's NchwcTransformer runs a Conv blocked only when its input channels are a multiple of the
NCHWc block (8 with AVX2, 16 with AVX-512) or below it; Concat, pooling and Resize stay
blocked only when every input is. WSKP's width-14 layers (Fan21) stayed plain NCHW convs, the
slowest path; AFN's 12-wide half scale and 14-channel input sent its skip concatenations back
to NCHW and through reorders. Two rewrites, both the same function:

- `pad_conv_widths`: a conv's output gets extra channels with zero weights (and bias). The
  extra channels are 0 and stay 0 through activations with f(0) = 0 (ReLU, LeakyReLU),
  average / max pooling, Resize and channel concatenation, and the convs that finally read
  them get zero weights for them (inserted where they sit in a concatenation).
- `pad_conv_inputs`: a channel concatenation read only by convs gets zero channels appended
  (ConstantOfShape, the input's batch and size), and its convs zero weights for them.

Measured at 720p on 2 cores: demo:wskp 14 -> 16 ran 0.76x the time per frame (outputs within
4e-7), demo:afn (12 -> 16 at its half scale, input 14 -> 16) 0.89x (within 1.2e-6);
benchmarks/README.md.
Only chains these rules cover are touched, and only where the growth is at most `max_growth`
(12 -> 16 yes; 4 -> 8 no: doubling a layer costs more than the layout saves).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

ZERO_PRESERVING = ("Relu", "LeakyRelu", "AveragePool", "MaxPool", "Resize")
CHANNEL_AXES = (1, -3)


def _group(node: onnx.NodeProto) -> int:
    return next((int(a.i) for a in node.attribute if a.name == "group"), 1)


def _axis(node: onnx.NodeProto) -> int | None:
    return next((int(a.i) for a in node.attribute if a.name == "axis"), None)


def ints_attribute(node: onnx.NodeProto, name: str) -> list[int] | None:
    """A node's list-of-ints attribute (a Conv's pads, strides ...), None when absent."""
    return next((list(a.ints) for a in node.attribute if a.name == name), None)


def auto_pad(node: onnx.NodeProto) -> bytes:
    """A Conv's auto_pad (NOTSET when absent)."""
    return next((a.s for a in node.attribute if a.name == "auto_pad"), b"NOTSET")


def is_standard(node: onnx.NodeProto) -> bool:
    """A node of the standard ONNX domain."""
    return node.domain in ("", "ai.onnx")


class Graph:
    """Consumers, initializers and inferred channel counts of a model's main graph."""

    def __init__(self, proto: onnx.ModelProto) -> None:
        self.proto = proto
        graph = proto.graph
        self.inits = {i.name: i for i in graph.initializer}
        self.consumers: dict[str, list[onnx.NodeProto]] = defaultdict(list)
        self.uses: dict[str, int] = defaultdict(int)  # initializers shared by nodes stay
        for n in graph.node:
            for i in n.input:
                self.consumers[i].append(n)
                self.uses[i] += 1
        self.outputs = {o.name for o in graph.output}
        inferred = onnx.shape_inference.infer_shapes(proto).graph
        self.channels: dict[str, int] = {}
        for v in (*inferred.value_info, *inferred.input, *inferred.output):
            dims = v.type.tensor_type.shape.dim
            if len(dims) == 4 and dims[1].HasField("dim_value"):
                self.channels[v.name] = dims[1].dim_value

    def plain_conv(self, n: onnx.NodeProto) -> bool:
        """A group-1 Conv whose weights (and bias) are initializers of its own."""
        return (
            n.op_type == "Conv"
            and is_standard(n)
            and _group(n) == 1
            and all(i in self.inits and self.uses[i] == 1 for i in n.input[1:] if i)
        )

    def readers(self, tensor: str, at: int) -> tuple[list, list[str]] | None:
        """Where channels inserted at index `at` of `tensor` end up: the convs that read them,
        (conv, index of the inserted channels in its input), and every tensor they pass through;
        None if anything but a plain conv, a zero-preserving op or a channel Concat reads them."""
        convs: list[tuple[onnx.NodeProto, int]] = []
        tensors: list[str] = []
        todo = [(tensor, at)]
        while todo:
            name, pos = todo.pop()
            if name in self.outputs or not self.consumers[name]:
                return None
            tensors.append(name)
            for c in self.consumers[name]:
                if self.plain_conv(c) and c.input[0] == name and name not in c.input[1:]:
                    convs.append((c, pos))
                elif (
                    c.op_type in ZERO_PRESERVING
                    and is_standard(c)
                    and list(c.input).count(name) == 1
                ):
                    sizes = c.op_type == "Resize" and len(c.input) > 3 and c.input[3]
                    extra = [
                        o for o in c.output[1:] if o and (self.consumers[o] or o in self.outputs)
                    ]
                    if c.input[0] != name or sizes or extra:
                        # a Resize given output sizes fixes the channel count; a MaxPool's
                        # indices would be read with the new channels
                        return None
                    todo.append((c.output[0], pos))
                elif c.op_type == "Concat" and is_standard(c) and _axis(c) in CHANNEL_AXES:
                    if list(c.input).count(name) != 1:
                        return None
                    before = c.input[: list(c.input).index(name)]
                    if any(i not in self.channels for i in before):
                        return None
                    todo.append((c.output[0], sum(self.channels[i] for i in before) + pos))
                else:
                    return None
        if len({id(c) for c, _ in convs}) != len(convs):
            return None  # one conv reached twice: leave it
        return convs, tensors

    def pad_conv_weights(self, convs: list, count: int) -> None:
        """Insert `count` zero input channels at each conv's index."""
        for conv, pos in convs:
            init = self.inits[conv.input[1]]
            w = numpy_helper.to_array(init)
            zeros = np.zeros((w.shape[0], count, *w.shape[2:]), w.dtype)
            _set(init, np.concatenate([w[:, :pos], zeros, w[:, pos:]], axis=1))

    def forget_shapes(self, names: set[str]) -> None:
        """Drop the stored shapes of `names` (ONNX Runtime and checkers re-infer them)."""
        graph = self.proto.graph
        kept = [v for v in graph.value_info if v.name not in names]
        del graph.value_info[:]
        graph.value_info.extend(kept)


def pad_conv_widths(
    proto: onnx.ModelProto, multiple: int = 8, max_growth: float = 1 / 3
) -> list[tuple[str, int, int]]:
    """Pad, in place, every eligible hidden conv width of the main graph to a multiple of
    `multiple`; returns (conv node name, old width, new width) per padded layer."""
    padded = []
    g = Graph(proto)
    for n in list(proto.graph.node):
        if not g.plain_conv(n):
            continue
        weight = numpy_helper.to_array(g.inits[n.input[1]])
        width = weight.shape[0]
        pad = -width % multiple
        found = g.readers(n.output[0], width) if pad and pad <= max_growth * width else None
        if found is None:
            continue
        convs, tensors = found
        extra = np.zeros((pad, *weight.shape[1:]), weight.dtype)
        _set(g.inits[n.input[1]], np.concatenate([weight, extra]))
        if len(n.input) > 2 and n.input[2]:
            bias = numpy_helper.to_array(g.inits[n.input[2]])
            _set(g.inits[n.input[2]], np.concatenate([bias, np.zeros(pad, bias.dtype)]))
        g.pad_conv_weights(convs, pad)
        g.forget_shapes({*tensors, *n.input[1:], *(c.input[1] for c, _ in convs)})
        padded.append((n.name, width, width + pad))
        g = Graph(proto)  # channel counts changed
    return padded


def pad_conv_inputs(
    proto: onnx.ModelProto, multiple: int = 8, max_growth: float = 0.25
) -> list[tuple[str, int, int]]:
    """Append, in place, zero channels to every channel Concat of the main graph that only
    convs read, up to a multiple of `multiple`; returns (Concat node name, old channels, new
    channels) per padded concatenation."""
    padded = []
    g = Graph(proto)
    for n in list(proto.graph.node):
        if n.op_type != "Concat" or not is_standard(n) or _axis(n) not in CHANNEL_AXES:
            continue
        out = n.output[0]
        channels = g.channels.get(out)
        if channels is None:
            continue
        pad = -channels % multiple
        readers = g.consumers[out]
        if (
            not pad
            or pad > max_growth * channels
            or out in g.outputs
            or not readers
            or not all(g.plain_conv(c) and c.input[0] == out for c in readers)
        ):
            continue
        zeros = _zeros_like_channels(proto.graph, n, pad)
        n.input.append(zeros)
        g.pad_conv_weights([(c, channels) for c in readers], pad)
        g.forget_shapes({out, *(c.input[1] for c in readers)})
        padded.append((n.name, channels, channels + pad))
        g = Graph(proto)
    return padded


def _zeros_like_channels(graph: onnx.GraphProto, concat: onnx.NodeProto, count: int) -> str:
    """Insert before `concat` nodes making zeros (N, count, H, W), N, H, W those of its first
    input; returns the tensor's name."""
    base = f"{concat.name}_zeros"
    nodes = constant_channels(graph, concat.input[0], count, 0.0, base)
    at = list(graph.node).index(concat)
    for k, node in enumerate(nodes):
        graph.node.insert(at + k, node)
    return base


def constant_channels(
    graph: onnx.GraphProto, like: str, count: int, value: float, base: str
) -> list[onnx.NodeProto]:
    """Nodes making `base` = `value` everywhere, shape (N, count, H, W) with N, H, W those of
    the 4-D tensor `like`, and on the way `<base>_n` = [N] and `<base>_hw` = [H, W]."""
    count_name = f"{base}_count"
    graph.initializer.append(numpy_helper.from_array(np.array([count], np.int64), count_name))
    fill = helper.make_tensor("value", TensorProto.FLOAT, [1], [value])
    return [
        helper.make_node("Shape", [like], [f"{base}_n"], name=f"{base}_n", start=0, end=1),
        helper.make_node("Shape", [like], [f"{base}_hw"], name=f"{base}_hw", start=2),
        helper.make_node(
            "Concat",
            [f"{base}_n", count_name, f"{base}_hw"],
            [f"{base}_shape"],
            axis=0,
            name=f"{base}_shape",
        ),
        helper.make_node("ConstantOfShape", [f"{base}_shape"], [base], name=base, value=fill),
    ]


def drop_unread_initializers(graph: onnx.GraphProto, names: set[str]) -> None:
    """Remove the initializers among `names` that no node and no graph input reads any more
    (a rewrite's leftovers; other initializers stay, read or not)."""
    read = {i for n in graph.node for i in n.input} | {i.name for i in graph.input}
    kept = [i for i in graph.initializer if i.name in read or i.name not in names]
    del graph.initializer[:]
    graph.initializer.extend(kept)


def _set(init: onnx.TensorProto, value: np.ndarray) -> None:
    init.CopyFrom(numpy_helper.from_array(value, init.name))
