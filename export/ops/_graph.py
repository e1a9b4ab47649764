"""A small node builder for function bodies too long to spell node by node (the Choi24 ops).

    g = Graph("cr")
    total = g.op("Add", "a", g.const(1.0))     # returns the fresh output name

Names are `<prefix><n>` unless given; constants are Constant nodes (float64 unless `dtype`).
"""

from __future__ import annotations

from collections.abc import Sequence

import onnx
from onnx import TensorProto, helper

DOUBLE = TensorProto.DOUBLE
FLOAT = TensorProto.FLOAT
INT64 = TensorProto.INT64


class Graph:
    """Collects nodes; every method returns the name(s) of what it made."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self.nodes: list[onnx.NodeProto] = []
        self._count = 0

    def name(self) -> str:
        self._count += 1
        return f"{self.prefix}{self._count}"

    def op(self, op_type: str, *inputs: str, out: str | None = None, **attrs) -> str:
        """One single-output node."""
        name = out or self.name()
        self.nodes.append(helper.make_node(op_type, list(inputs), [name], **attrs))
        return name

    def ops(self, op_type: str, inputs: Sequence[str], count: int, **attrs) -> list[str]:
        """One node with `count` outputs (e.g. Split)."""
        names = [self.name() for _ in range(count)]
        self.nodes.append(helper.make_node(op_type, list(inputs), names, **attrs))
        return names

    def node(self, node: onnx.NodeProto) -> None:
        self.nodes.append(node)

    def const(self, value: float | int | Sequence, dtype: int = DOUBLE) -> str:
        """A Constant: a scalar for a number, a 1-D tensor for a sequence."""
        values = list(value) if isinstance(value, Sequence) else [value]
        dims = [len(values)] if isinstance(value, Sequence) else []
        tensor = helper.make_tensor("", dtype, dims, values)
        return self.op("Constant", value=tensor)

    def ints(self, *values: int) -> str:
        """A 1-D int64 Constant."""
        return self.const(list(values), INT64)

    def slice(self, x: str, start: int, end: int, axis: int) -> str:
        """x[start:end] along one axis (constant bounds)."""
        return self.op("Slice", x, self.ints(start), self.ints(end), self.ints(axis))

    def unsqueeze(self, x: str, *axes: int) -> str:
        return self.op("Unsqueeze", x, self.ints(*axes))
