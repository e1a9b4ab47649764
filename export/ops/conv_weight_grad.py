"""ConvWeightGrad as an ONNX function body; spec: rtdenoise.ops.conv_weight_grad.

Body: the torch form's convolution of the batch-transposed tensors: Transpose both to
(C, N, H, W), Conv(input^T, grad_output^T) with the op's padding, Transpose back to
(C_out, C_in, K, K).
"""

from __future__ import annotations

import onnx
from onnx import helper

from .base import function_body


@function_body("ConvWeightGrad")
def conv_weight_grad_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.ConvWeightGrad in standard ops (see the module docstring). Conv's `pads` is
    an attribute list, so the padding reaches it through a Pad of the input instead."""
    mk = helper.make_node
    pad_ref = onnx.AttributeProto(name="value_int", type=onnx.AttributeProto.INT)
    pad_ref.ref_attr_name = "padding"
    pad_node = mk("Constant", [], ["p"])
    pad_node.attribute.append(pad_ref)
    return [
        pad_node,
        mk("Constant", [], ["zero"], value_ints=[0]),
        mk("Unsqueeze", ["p", "zero"], ["p1"]),
        mk("Concat", ["zero", "zero", "p1", "p1", "zero", "zero", "p1", "p1"], ["pads"], axis=0),
        mk("Pad", ["input", "pads"], ["padded"]),
        mk("Transpose", ["padded"], ["x_t"], perm=[1, 0, 2, 3]),
        mk("Transpose", ["grad_output"], ["g_t"], perm=[1, 0, 2, 3]),
        mk("Conv", ["x_t", "g_t"], ["per_input"]),
        mk("Transpose", ["per_input"], ["grad_weight"], perm=[1, 0, 2, 3]),
    ]
