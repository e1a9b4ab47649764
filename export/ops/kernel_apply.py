"""KernelApply as an ONNX function body (Lee24 eq. (2)); defined in rtdenoise.ops.kernel_apply.

Body: edge-Pad once, then a Loop over the k*k taps accumulating
kernel[:, t] * shifted window (works for any k, dilation and dynamic H, W).
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import attr_const, function_body, int_const


def _loop_body() -> onnx.GraphProto:
    """One tap t: acc += kernel[:, t:t+1] * padded[:, :, i*d : i*d+H, j*d : j*d+W]."""
    mk = helper.make_node
    nodes = [
        int_const("b_zero", [0]),
        int_const("b_one", [1]),
        int_const("b_axes_hw", [2, 3]),
        int_const("b_axis_c", [1]),
        mk("Div", ["t", "k"], ["b_i"]),
        mk("Mod", ["t", "k"], ["b_j"]),
        mk("Mul", ["b_i", "d"], ["b_sy"]),
        mk("Mul", ["b_j", "d"], ["b_sx"]),
        mk("Unsqueeze", ["b_sy", "b_zero"], ["b_sy1"]),
        mk("Unsqueeze", ["b_sx", "b_zero"], ["b_sx1"]),
        mk("Concat", ["b_sy1", "b_sx1"], ["b_starts"], axis=0),
        mk("Add", ["b_starts", "hw"], ["b_ends"]),
        mk("Slice", ["padded", "b_starts", "b_ends", "b_axes_hw"], ["b_window"]),
        mk("Unsqueeze", ["t", "b_zero"], ["b_t1"]),
        mk("Add", ["b_t1", "b_one"], ["b_t2"]),
        mk("Slice", ["kernel", "b_t1", "b_t2", "b_axis_c"], ["b_tap"]),
        mk("Mul", ["b_tap", "b_window"], ["b_term"]),
        mk("Add", ["acc_in", "b_term"], ["acc_out"]),
        mk("Identity", ["cond_in"], ["cond_out"]),
    ]
    return helper.make_graph(
        nodes,
        "kernel_apply_tap",
        [
            helper.make_tensor_value_info("t", TensorProto.INT64, []),
            helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
            helper.make_tensor_value_info("acc_in", TensorProto.FLOAT, None),
        ],
        [
            helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
            helper.make_tensor_value_info("acc_out", TensorProto.FLOAT, None),
        ],
    )


@function_body("KernelApply")
def kernel_apply_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.KernelApply in standard ops."""
    mk = helper.make_node
    return [
        attr_const("k", "kernel_size"),
        attr_const("d", "dilation"),
        int_const("two", 2),
        int_const("zeros2", [0, 0]),
        int_const("hw_start", [2]),
        int_const("hw_end", [4]),
        mk("Div", ["k", "two"], ["r"]),
        mk("Mul", ["r", "d"], ["p"]),
        int_const("shape1", [1]),
        mk("Reshape", ["p", "shape1"], ["p1"]),
        # pads = [0, 0, p, p, 0, 0, p, p] (begins of N, C, H, W, then ends)
        mk("Concat", ["zeros2", "p1", "p1", "zeros2", "p1", "p1"], ["pads"], axis=0),
        mk("Pad", ["image", "pads"], ["padded"], mode="edge"),
        mk("Shape", ["image"], ["shape"]),
        mk("Slice", ["shape", "hw_start", "hw_end"], ["hw"]),
        mk("ConstantOfShape", ["shape"], ["acc0"], value=helper.make_tensor("", 1, [1], [0.0])),
        mk("Mul", ["k", "k"], ["taps"]),
        mk("Loop", ["taps", "", "acc0"], ["output"], body=_loop_body()),
    ]
