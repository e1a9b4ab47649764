"""SoftmaxKernelApply as an ONNX function body; defined in rtdenoise.ops.softmax_kernel_apply.

Body: the softmax over axis 1 of the logits spelled out (ReduceMax, Sub, Exp, ReduceSum, Div,
as in KernelFusion: ORT's Softmax(axis=1) on NCHW is slow), then KernelApply's body on it.
"""

from __future__ import annotations

import onnx
from onnx import helper

from .base import function_body, int_const
from .kernel_apply import kernel_apply_body


@function_body("SoftmaxKernelApply")
def softmax_kernel_apply_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.SoftmaxKernelApply in standard ops."""
    mk = helper.make_node
    if opset >= 18:  # axes became an input of ReduceMax in opset 18
        reduce_max = mk("ReduceMax", ["logits", "sk_axis"], ["sk_top"], keepdims=1)
    else:
        reduce_max = mk("ReduceMax", ["logits"], ["sk_top"], axes=[1], keepdims=1)
    softmax = [
        int_const("sk_axis", [1]),
        reduce_max,
        mk("Sub", ["logits", "sk_top"], ["sk_shifted"]),
        mk("Exp", ["sk_shifted"], ["sk_e"]),
        mk("ReduceSum", ["sk_e", "sk_axis"], ["sk_total"], keepdims=1),
        mk("Div", ["sk_e", "sk_total"], ["kernel"]),
    ]
    return softmax + kernel_apply_body.body(opset)
