"""NeighbourBlend in standard ONNX ops: the portable body any ONNX Runtime runs."""

from __future__ import annotations

import onnx
from onnx import helper

from rtdenoise.export.ops import function_body
from rtdenoise.export.ops.base import int_const

from . import op_spec  # noqa: F401  (the spec, before its form)


@function_body("NeighbourBlend")
def neighbour_blend_body(opset: int) -> list[onnx.NodeProto]:
    mk = helper.make_node
    return [
        int_const("pads", [0, 0, 1, 1, 0, 0, 1, 1]),
        mk("Pad", ["image", "pads"], ["padded"], mode="edge"),
        mk("AveragePool", ["padded"], ["box"], kernel_shape=[3, 3]),
        mk("Sub", ["box", "image"], ["detail"]),
        mk("Mul", ["weight", "detail"], ["step"]),
        mk("Add", ["image", "step"], ["output"]),
    ]
