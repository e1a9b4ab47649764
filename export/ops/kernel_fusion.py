"""KernelFusion as an ONNX function body (Fan21); defined in rtdenoise.ops.kernel_fusion.

Body: softmax over axis 1 of the logits (ReduceMax, Sub, Exp, ReduceSum, Div), images
reshaped to (N, S, C, H, W), Mul with the unsqueezed probabilities, ReduceSum over S.
"""

from __future__ import annotations

import onnx
from onnx import helper

from .base import function_body, int_const, softmax_axis1


@function_body("KernelFusion")
def kernel_fusion_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.KernelFusion in standard ops."""
    mk = helper.make_node
    return [
        int_const("zero", [0]),
        int_const("one", [1]),
        int_const("two", [2]),
        int_const("four", [4]),
        int_const("minus1", [-1]),
        *softmax_axis1("logits", "p", "sm_", opset),
        mk("Shape", ["images"], ["shape"]),
        mk("Slice", ["shape", "zero", "one"], ["n"]),
        mk("Slice", ["shape", "two", "four"], ["hw"]),
        mk("Shape", ["logits"], ["lshape"]),
        mk("Slice", ["lshape", "one", "two"], ["s"]),
        mk("Concat", ["n", "s", "minus1", "hw"], ["shape5"], axis=0),
        mk("Reshape", ["images", "shape5"], ["images5"]),
        mk("Unsqueeze", ["p", "two"], ["p5"]),
        mk("Mul", ["p5", "images5"], ["weighted"]),
        mk("ReduceSum", ["weighted", "one"], ["output"], keepdims=0),
    ]
