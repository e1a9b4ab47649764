"""An index of a graph for the export passes that match node patterns: who produces and who
reads each value, the constant initializers as arrays, the graph outputs."""

from __future__ import annotations

import numpy as np
import onnx
from onnx import numpy_helper

from .conv_widths import is_standard


class GraphIndex:
    """Producers, readers, constant initializers and outputs of `graph` (one snapshot: make a
    new one after rewriting the graph)."""

    def __init__(self, graph: onnx.GraphProto) -> None:
        self.graph = graph
        self.consts: dict[str, np.ndarray] = {
            i.name: numpy_helper.to_array(i) for i in graph.initializer
        }
        self.producer = {o: n for n in graph.node for o in n.output}
        self.readers: dict[str, list[onnx.NodeProto]] = {}
        for n in graph.node:
            for i in n.input:
                self.readers.setdefault(i, []).append(n)
        self.outputs = {o.name for o in graph.output}

    def made_by(self, name: str, op: str) -> onnx.NodeProto | None:
        """The standard-domain node of type `op` that produces `name`, else None."""
        node = self.producer.get(name)
        return node if node is not None and node.op_type == op and is_standard(node) else None

    def const(self, name: str) -> list[int] | None:
        """A constant initializer's values as ints (None for anything else)."""
        value = self.consts.get(name)
        return None if value is None else [int(v) for v in value.reshape(-1)]

    def sole_reader(self, name: str) -> onnx.NodeProto | None:
        """The one node that reads `name`, if only one does and it is no graph output."""
        readers = self.readers.get(name, [])
        return readers[0] if len(readers) == 1 and name not in self.outputs else None
