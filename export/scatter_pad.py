"""Write a slice_scatter into zeros as a Pad, at export.

torch.onnx spells `slice_scatter(zeros, x, dim=k, start=s, end=e)` (the traced backward of a
channel slice: crossreg's gradient reaching a part of a concatenation) as a ScatterND between
two Transposes that bring axis k to the front:

    Transpose(ScatterND(Transpose(zeros), Unsqueeze(Slice(Range(0, n), s, e)), Transpose(x)))

which copies the zeros, transposes three full tensors and scatters x row by row: 6 such nodes
took 37 ms of demo:crossreg's 720p learning frame. Where the zeros' size n along k is a
constant of the graph, the same tensor is Pad(x) with s zeros before x on axis k and
n - min(e, n) after it, exactly (a copy either way). `slice_scatter_as_pad` rewrites each such
pattern of the main graph; nodes left unread by it are removed.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .conv_widths import is_standard
from .graph_index import GraphIndex


def _attr(node: onnx.NodeProto, name: str, default=None):
    for a in node.attribute:
        if a.name == name:
            return helper.get_attribute_value(a)
    return default


def _swap_axis(perm: list[int]) -> int | None:
    """k where `perm` swaps axes 0 and k (k > 0) and keeps the others; else None."""
    k = perm[0] if perm else 0
    expected = list(range(len(perm)))
    if k <= 0 or k >= len(perm):
        return None
    expected[0], expected[k] = k, 0
    return k if perm == expected else None


class _Pattern(GraphIndex):
    """A GraphIndex that also finds Transposes swapping axes 0 and k."""

    def transposed_by(self, name: str, k: int) -> onnx.NodeProto | None:
        node = self.made_by(name, "Transpose")
        perm = list(_attr(node, "perm", [])) if node is not None else []
        return node if node is not None and _swap_axis(perm) == k else None


def _zeros_size(p: _Pattern, zeros: onnx.NodeProto, k: int) -> int | None:
    """The size along axis k of a ConstantOfShape of 0 whose shape is a Concat of 1-element
    parts, the k-th a constant."""
    value = _attr(zeros, "value")
    if value is not None and numpy_helper.to_array(value).any():
        return None
    shape = p.made_by(zeros.input[0], "Concat")
    if shape is None or len(shape.input) <= k:
        return None
    part = p.const(shape.input[k])
    return part[0] if part is not None and len(part) == 1 else None


def _slice_range(
    p: _Pattern, indices: str, zeros: onnx.NodeProto, k: int
) -> tuple[int, int] | None:
    """(start, end) where `indices` is Unsqueeze(Slice(Range(0, n, 1), start, end, axis 0,
    step 1), -1) with n the zeros' size along k (Shape -> Gather k)."""
    unsqueeze = p.made_by(indices, "Unsqueeze")
    if (
        unsqueeze is None
        or len(unsqueeze.input) != 2
        or p.const(unsqueeze.input[1]) not in ([-1], [1])
    ):
        return None
    sliced = p.made_by(unsqueeze.input[0], "Slice")
    if sliced is None or len(sliced.input) < 4:
        return None
    starts, ends, axes = (p.const(i) for i in sliced.input[1:4])
    steps = p.const(sliced.input[4]) if len(sliced.input) > 4 else [1]
    if starts is None or ends is None or axes not in ([0], [-1]) or steps != [1]:
        return None
    rng = p.made_by(sliced.input[0], "Range")
    if rng is None or p.const(rng.input[0]) not in ([0],) or p.const(rng.input[2]) != [1]:
        return None
    gather = p.made_by(rng.input[1], "Gather")
    shape = p.made_by(gather.input[0], "Shape") if gather is not None else None
    if (
        shape is None
        or shape.input[0] != zeros.output[0]
        or _attr(shape, "start", 0) != 0
        or _attr(shape, "end") is not None
        or p.const(gather.input[1]) != [k]
        or _attr(gather, "axis", 0) != 0
    ):
        return None
    return starts[0], ends[0]


def _remove_unread(graph: onnx.GraphProto, candidates: set[str]) -> None:
    """Drop, repeatedly, nodes among `candidates` (by name) whose outputs nothing reads."""
    outputs = {o.name for o in graph.output}
    while True:
        read = {i for n in graph.node for i in n.input} | outputs
        dead = [
            n for n in graph.node if n.name in candidates and not any(o in read for o in n.output)
        ]
        if not dead:
            return
        for n in dead:
            graph.node.remove(n)


def slice_scatter_as_pad(proto: onnx.ModelProto) -> list[str]:
    """Rewrite each slice_scatter-into-zeros pattern of the main graph (module docstring) as a
    Pad; returns the names of the ScatterND nodes replaced."""
    graph = proto.graph
    p = _Pattern(graph)
    done: list[str] = []
    candidates: set[str] = set()
    for scatter in [n for n in graph.node if n.op_type == "ScatterND" and is_standard(n)]:
        if _attr(scatter, "reduction", b"none") not in (b"none", "none"):
            continue
        readers = p.readers.get(scatter.output[0], [])
        if len(readers) != 1 or scatter.output[0] in p.outputs:
            continue
        back = readers[0]
        perm = list(_attr(back, "perm", [])) if back.op_type == "Transpose" else []
        k = _swap_axis(perm)
        data = p.transposed_by(scatter.input[0], k) if k is not None else None
        updates = p.transposed_by(scatter.input[2], k) if k is not None else None
        zeros = p.made_by(data.input[0], "ConstantOfShape") if data is not None else None
        if updates is None or zeros is None:
            continue
        size = _zeros_size(p, zeros, k)
        span = _slice_range(p, scatter.input[1], zeros, k)
        if size is None or span is None:
            continue
        start, end = (min(max(v if v >= 0 else v + size, 0), size) for v in span)
        if end <= start:
            continue
        rank = len(perm)
        pads = [0] * (2 * rank)
        pads[k], pads[rank + k] = start, size - end
        name = f"{scatter.name or scatter.output[0]}_as_pad"
        graph.initializer.append(numpy_helper.from_array(np.array(pads, np.int64), f"{name}.pads"))
        pad = helper.make_node(
            "Pad", [updates.input[0], f"{name}.pads"], [back.output[0]], name=name, mode="constant"
        )
        at = list(graph.node).index(back)
        graph.node.remove(back)
        graph.node.insert(at, pad)
        candidates |= {n.name for n in graph.node if n.name} & {
            scatter.name,
            data.name,
            updates.name,
            zeros.name,
        }
        done.append(scatter.name or scatter.output[0])
        p = _Pattern(graph)
    if done:
        _remove_unread(graph, _pattern_producers(graph, candidates))
    return done


def _pattern_producers(graph: onnx.GraphProto, names: set[str]) -> set[str]:
    """`names` and every node upstream of them that only they (transitively) read: the index
    chain (Unsqueeze, Slice, Range, Gather, Shape) and the zeros' shape."""
    producer = {o: n for n in graph.node for o in n.output}
    by_name = {n.name: n for n in graph.node if n.name}
    out, todo = set(names), [by_name[n] for n in names if n in by_name]
    while todo:
        node = todo.pop()
        for i in node.input:
            src = producer.get(i)
            if src is not None and src.name and src.name not in out and is_standard(src):
                out.add(src.name)
                todo.append(src)
    return out
