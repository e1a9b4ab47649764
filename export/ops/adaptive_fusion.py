"""AdaptiveFusion as an ONNX function body (Lee24 eq. (3)); spec: rtdenoise.ops.adaptive_fusion.

Body: out = d_ta + alpha * U(d_low - D(d_ta)), D = AveragePool 2x2 stride 2,
U = Resize nearest x2 (asymmetric, floor): eq. (3) with the two alpha terms merged.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import function_body


@function_body("AdaptiveFusion")
def adaptive_fusion_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.AdaptiveFusion in standard ops."""
    mk = helper.make_node
    scales = helper.make_tensor("", TensorProto.FLOAT, [4], [1.0, 1.0, 2.0, 2.0])
    return [
        mk("AveragePool", ["d_ta"], ["pooled"], kernel_shape=[2, 2], strides=[2, 2]),
        mk("Sub", ["d_low", "pooled"], ["diff"]),
        mk("Constant", [], ["scales"], value=scales),
        mk(
            "Resize",
            ["diff", "", "scales"],
            ["up"],
            mode="nearest",
            coordinate_transformation_mode="asymmetric",
            nearest_mode="floor",
        ),
        mk("Mul", ["alpha", "up"], ["delta"]),
        mk("Add", ["d_ta", "delta"], ["output"]),
    ]
