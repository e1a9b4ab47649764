"""SoftmaxKernelApply as an ONNX function body; defined in rtdenoise.ops.softmax_kernel_apply.

Body: the softmax over axis 1 of the logits spelled out (ReduceMax, Sub, Exp, ReduceSum, Div,
as in KernelFusion: ORT's Softmax(axis=1) on NCHW is slow), then KernelApply's body on it.
"""

from __future__ import annotations

import onnx

from .base import function_body, softmax_axis1
from .kernel_apply import kernel_apply_body


@function_body("SoftmaxKernelApply")
def softmax_kernel_apply_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.SoftmaxKernelApply in standard ops."""
    return softmax_axis1("logits", "kernel", "sk_", opset) + kernel_apply_body.body(opset)
