"""Zero-pad hidden conv widths to a multiple of 8 at export, so ONNX Runtime's CPU convs take
their blocked (NCHWc) layout.

ORT's NchwcTransformer converts a Conv only when its output channels are a multiple of the
NCHWc block (8 with AVX2, 16 with AVX-512); WSKP's width-14 layers (Fan21) stayed plain NCHW
convs, the slowest path. A hidden layer padded with output channels whose weights (and bias)
are zero, read by the next conv with zero weights, computes the same function: the extra
channels are 0 and an activation with f(0) = 0 (ReLU, LeakyReLU) keeps them 0. Measured at
720p on 2 cores: demo:wskp 14 -> 16 ran 0.76x the time per frame, outputs within 4e-7
(benchmarks/README.md, "Runtime speed").

Only chains the rewrite provably preserves are touched: Conv (group 1, weights and bias
initializers) -> [Relu | LeakyRelu] -> Convs only, the tensors graph-internal, and the growth at
most `max_growth` (14 -> 16 yes; 4 -> 8 no: doubling a layer costs more than the layout saves).
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import onnx
from onnx import numpy_helper

ZERO_PRESERVING = ("Relu", "LeakyRelu")


def _group(node: onnx.NodeProto) -> int:
    return next((int(a.i) for a in node.attribute if a.name == "group"), 1)


def pad_conv_widths(
    proto: onnx.ModelProto, multiple: int = 8, max_growth: float = 0.25
) -> list[tuple[str, int, int]]:
    """Pad, in place, every eligible hidden conv width of the main graph to a multiple of
    `multiple`; returns (conv node name, old width, new width) per padded layer."""
    graph = proto.graph
    inits = {i.name: i for i in graph.initializer}
    consumers: dict[str, list[onnx.NodeProto]] = defaultdict(list)
    for n in graph.node:
        for i in n.input:
            consumers[i].append(n)
    outputs = {o.name for o in graph.output}
    uses = defaultdict(int)  # initializers shared by several nodes are left alone
    for n in graph.node:
        for i in n.input:
            uses[i] += 1

    def plain_conv(n: onnx.NodeProto) -> bool:
        return (
            n.op_type == "Conv"
            and n.domain in ("", "ai.onnx")
            and _group(n) == 1
            and all(i in inits and uses[i] == 1 for i in n.input[1:])
        )

    def readers(n: onnx.NodeProto) -> tuple[list[onnx.NodeProto], list[str]] | None:
        """The convs reading `n`'s output (directly or through one zero-preserving
        activation) and the tensors whose width changes; None if anything else reads it."""
        out = n.output[0]
        if out in outputs:
            return None
        convs, tensors = [], [out]
        for c in consumers[out]:
            if plain_conv(c) and c.input[0] == out:
                convs.append(c)
            elif c.op_type in ZERO_PRESERVING and c.domain in ("", "ai.onnx"):
                act = c.output[0]
                nxt = consumers[act]
                if (
                    act in outputs
                    or not nxt
                    or not all(plain_conv(d) and d.input[0] == act for d in nxt)
                ):
                    return None
                convs += nxt
                tensors.append(act)
            else:
                return None
        return (convs, tensors) if convs else None

    padded = []
    for n in list(graph.node):
        if not plain_conv(n):
            continue
        weight = numpy_helper.to_array(inits[n.input[1]])
        width = weight.shape[0]
        pad = -width % multiple
        found = readers(n)
        if not pad or pad > max_growth * width or found is None:
            continue
        convs, tensors = found
        extra = np.zeros((pad, *weight.shape[1:]), weight.dtype)
        _set(inits[n.input[1]], np.concatenate([weight, extra]))
        if len(n.input) > 2 and n.input[2]:
            bias = numpy_helper.to_array(inits[n.input[2]])
            _set(inits[n.input[2]], np.concatenate([bias, np.zeros(pad, bias.dtype)]))
        for c in convs:
            w = numpy_helper.to_array(inits[c.input[1]])
            zeros = np.zeros((w.shape[0], pad, *w.shape[2:]), w.dtype)
            _set(inits[c.input[1]], np.concatenate([w, zeros], axis=1))
        changed = {*tensors, *n.input[1:], *(c.input[1] for c in convs)}
        kept = [v for v in graph.value_info if v.name not in changed]  # shapes re-inferred
        del graph.value_info[:]
        graph.value_info.extend(kept)
        padded.append((n.name, width, width + pad))
    return padded


def _set(init: onnx.TensorProto, value: np.ndarray) -> None:
    init.CopyFrom(numpy_helper.from_array(value, init.name))
