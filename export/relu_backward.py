"""Write the traced backward of a ReLU as a multiply by its mask, at export.

aten's `threshold_backward(grad, relu_out, 0)` reaches ONNX as
`Where(LessOrEqual(relu_out, 0), 0, grad)`. ONNX Runtime's Where is slow on the CPU: at 720p on
2 cores, 85 ms for an 8-channel tensor where Greater + Cast + Mul take 17 (one-op sessions,
2026-12-07); demo:crossreg's learning branch has nine, 117 ms of its backward.
`relu_backward_as_mul` writes each as `Mul(grad, Cast(Greater(relu_out, 0), float))`: 1 where
the ReLU passed, 0 where it did not. The values are the same for a finite gradient (a masked
one is +-0 instead of +0, equal as numbers); a NaN or infinite gradient at a masked pixel
would pass where Where dropped it, so only this pattern is rewritten: the mask from a Relu's
output compared with a constant 0, read by this Where alone, its first branch the constant 0.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from .conv_widths import is_standard
from .graph_index import GraphIndex


def _zero_scalar(name: str, consts: dict[str, np.ndarray]) -> bool:
    value = consts.get(name)
    return value is not None and value.size == 1 and float(value.reshape(-1)[0]) == 0.0


def relu_backward_as_mul(proto: onnx.ModelProto) -> list[str]:
    """Rewrite, in place, each ReLU backward Where of the main graph (module docstring);
    returns the names of the Where nodes replaced."""
    graph = proto.graph
    g = GraphIndex(graph)
    replace: dict[str, list[onnx.NodeProto]] = {}  # Where output -> its nodes
    drop: set[str] = set()  # LessOrEqual outputs
    done = []
    for where in graph.node:
        if where.op_type != "Where" or not is_standard(where) or len(where.input) != 3:
            continue
        mask = g.made_by(where.input[0], "LessOrEqual")
        if (
            mask is None
            or g.sole_reader(mask.output[0]) is None
            or g.made_by(mask.input[0], "Relu") is None
            or not _zero_scalar(mask.input[1], g.consts)
            or not _zero_scalar(where.input[1], g.consts)
        ):
            continue
        base = where.name or where.output[0]
        replace[where.output[0]] = [
            helper.make_node(
                "Greater", [mask.input[0], mask.input[1]], [f"{base}_on"], name=f"{base}_on"
            ),
            helper.make_node(
                "Cast", [f"{base}_on"], [f"{base}_gate"], name=f"{base}_gate", to=TensorProto.FLOAT
            ),
            helper.make_node(
                "Mul", [where.input[2], f"{base}_gate"], [where.output[0]], name=f"{base}_as_mul"
            ),
        ]
        drop.add(mask.output[0])
        done.append(where.name or where.output[0])
    if not done:
        return done
    nodes = []
    for n in graph.node:
        if n.output and n.output[0] in drop:
            continue
        if n.op_type == "Where" and n.output and n.output[0] in replace:
            nodes += replace[n.output[0]]
            continue
        nodes.append(n)
    del graph.node[:]
    graph.node.extend(nodes)
    return done
