"""Compute the channel offsets of MaxPool's indices from the input's shape, at export.

ONNX's MaxPool numbers its Indices over the whole tensor ((n C + c) H W + y W + x); torch's
`max_pool2d_with_indices` counts within each (n, c) plane. The exporter turns one into the
other by subtracting the first index of each plane, which it gets from a second MaxPool: a 1 x 1
pool of the same input whose Indices are sliced to [:, :, 0:1, 0:1]. That pool reads and writes
the whole input (an int64 index per element) to learn N x C numbers: in demo:crossreg's
backward two of them took 52 ms of a 720p learning frame.

`pool_index_offsets` replaces each such pool (kernel, strides and dilations 1, no padding, its
values unread, its Indices read only by those slices) by the same numbers from the input's
shape: Range(N C) x (H W), reshaped to (N, C, 1, 1). The slices stay (on a (N, C, 1, 1) tensor
they select all of it), so the result is the same int64 tensor, exactly.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .conv_widths import auto_pad, ints_attribute, is_standard


def _is_unit_pool(node: onnx.NodeProto) -> bool:
    """A 2-D MaxPool with both outputs whose window is one element (kernel, strides, dilations
    1, no padding, no auto_pad)."""
    if node.op_type != "MaxPool" or not is_standard(node) or len(node.output) != 2:
        return False
    kernel = ints_attribute(node, "kernel_shape") or []
    pads = ints_attribute(node, "pads") or []
    storage = next((a.i for a in node.attribute if a.name == "storage_order"), 0)
    return (
        len(kernel) == 2  # a 2-D pool: (N, C, H, W), the offsets (N, C, 1, 1)
        and all(k == 1 for k in kernel)
        and all(s == 1 for s in (ints_attribute(node, "strides") or []))
        and all(d == 1 for d in (ints_attribute(node, "dilations") or []))
        and all(p == 0 for p in pads)
        and auto_pad(node) in (b"NOTSET", b"VALID")
        and storage == 0
    )


def _is_first_element_slice(node: onnx.NodeProto, inits: dict[str, np.ndarray]) -> bool:
    """A Slice of its data's spatial axes 2, 3 (or -2, -1) to [0:1], step 1."""
    if node.op_type != "Slice" or not is_standard(node) or len(node.input) < 4:
        return False
    values = [inits.get(name) for name in node.input[1:5] if name]
    if any(v is None for v in values):
        return False
    starts, ends, axes, *steps = (v.reshape(-1).tolist() for v in values)
    return (
        sorted(a % 4 for a in axes) == [2, 3]
        and all(s == 0 for s in starts)
        and all(e == 1 for e in ends)
        and all(s == 1 for s in (steps[0] if steps else []))
    )


def pool_index_offsets(proto: onnx.ModelProto) -> list[str]:
    """Rewrite, in place, each 1 x 1 MaxPool of the main graph that only serves its Indices'
    plane offsets (see the module docstring); returns the names of the replaced nodes."""
    graph = proto.graph
    inits = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    readers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            readers.setdefault(name, []).append(node)
    outputs = {o.name for o in graph.output}
    nodes, done, constants = [], [], False
    for node in graph.node:
        values, indices = (node.output[0], node.output[1]) if len(node.output) == 2 else ("", "")
        if not (
            _is_unit_pool(node)
            and (not values or (values not in readers and values not in outputs))
            and indices not in outputs
            and readers.get(indices)
            and all(_is_first_element_slice(r, inits) for r in readers[indices])
        ):
            nodes.append(node)
            continue
        x, base = node.input[0], node.name or indices
        nodes += [
            helper.make_node("Shape", [x], [f"{base}_nc"], name=f"{base}_nc", start=0, end=2),
            helper.make_node("Shape", [x], [f"{base}_hw"], name=f"{base}_hw", start=2),
            helper.make_node("ReduceProd", [f"{base}_nc"], [f"{base}_planes"],
                             name=f"{base}_planes", keepdims=0),
            helper.make_node("ReduceProd", [f"{base}_hw"], [f"{base}_area"],
                             name=f"{base}_area", keepdims=1),
            helper.make_node("Range", ["pool_offsets_zero", f"{base}_planes", "pool_offsets_one"],
                             [f"{base}_plane"], name=f"{base}_plane"),
            helper.make_node("Mul", [f"{base}_plane", f"{base}_area"], [f"{base}_first"],
                             name=f"{base}_first"),
            helper.make_node("Concat", [f"{base}_nc", "pool_offsets_ones"], [f"{base}_shape"],
                             name=f"{base}_shape", axis=0),
            helper.make_node("Reshape", [f"{base}_first", f"{base}_shape"], [indices],
                             name=f"{base}_offsets"),
        ]  # fmt: skip
        done.append(node.name)
        constants = True
    if constants:
        graph.initializer.extend(
            [
                numpy_helper.from_array(np.array(0, np.int64), "pool_offsets_zero"),
                numpy_helper.from_array(np.array(1, np.int64), "pool_offsets_one"),
                numpy_helper.from_array(np.array([1, 1], np.int64), "pool_offsets_ones"),
            ]
        )
    del graph.node[:]
    graph.node.extend(nodes)
    return done
