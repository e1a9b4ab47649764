"""WeightSharingFilter as an ONNX function body (Fan21); defined in
rtdenoise.ops.weight_sharing_filter.

Body: a Loop over the sizes. Iteration i stacks [w_i * image, w_i] as (N*(C+1), 1, H, W)
planes, zero-Pads them by s//2 and box-sums them with two Convs against all-ones 1 x s and
s x 1 kernels built at run time (ConstantOfShape: kernel size from the attributes, H and W
dynamic), then divides (Where: 0 where the weight sum is not positive). The scan output
(S, N, C, H, W) is transposed and reshaped to (N, S*C, H, W).
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import attr_const, float_const, function_body, int_const


def _loop_body() -> onnx.GraphProto:
    """Size i: out_i = boxsum_s(w_i * image) / boxsum_s(w_i), s = size_min + i * size_step."""
    mk = helper.make_node
    nodes = [
        int_const("b_zero", [0]),
        int_const("b_one", [1]),
        int_const("b_minus1", [-1]),
        int_const("b_big", [2**62]),
        int_const("b_zeros2", [0, 0]),
        int_const("b_ones2", [1, 1]),
        int_const("b_ones3", [1, 1, 1]),
        int_const("b_two", 2),
        float_const("b_fzero", 0.0),
        float_const("b_fone", 1.0),
        # s and r = s // 2 as 1-element tensors
        mk("Mul", ["i", "step"], ["b_is"]),
        mk("Add", ["smin", "b_is"], ["b_s"]),
        mk("Div", ["b_s", "b_two"], ["b_r"]),
        mk("Reshape", ["b_s", "b_one"], ["b_s1"]),
        mk("Reshape", ["b_r", "b_one"], ["b_r1"]),
        # planes [w_i * image, w_i] -> (N*(C+1), 1, H, W)
        mk("Reshape", ["i", "b_one"], ["b_i1"]),
        mk("Add", ["b_i1", "b_one"], ["b_i2"]),
        mk("Slice", ["weights", "b_i1", "b_i2", "b_one"], ["b_w"]),
        mk("Mul", ["image", "b_w"], ["b_prod"]),
        mk("Concat", ["b_prod", "b_w"], ["b_stack"], axis=1),
        mk("Shape", ["b_stack"], ["b_stack_shape"]),
        mk("Reshape", ["b_stack", "plane_shape"], ["b_planes"]),
        # zero padding by r on both sides of H and W
        mk("Concat", ["b_zeros2", "b_r1", "b_r1", "b_zeros2", "b_r1", "b_r1"], ["b_pads"], axis=0),
        mk("Pad", ["b_planes", "b_pads"], ["b_padded"], mode="constant"),
        # separable box sum: all-ones (1 x s) then (s x 1) kernels
        mk("Concat", ["b_ones3", "b_s1"], ["b_kh_shape"], axis=0),
        mk("Concat", ["b_ones2", "b_s1", "b_one"], ["b_kv_shape"], axis=0),
        mk("ConstantOfShape", ["b_kh_shape"], ["b_kh"], value=_ones_value()),
        mk("ConstantOfShape", ["b_kv_shape"], ["b_kv"], value=_ones_value()),
        mk("Conv", ["b_padded", "b_kh"], ["b_hsum"]),
        mk("Conv", ["b_hsum", "b_kv"], ["b_box"]),
        mk("Reshape", ["b_box", "b_stack_shape"], ["b_boxes"]),
        mk("Slice", ["b_boxes", "b_zero", "b_minus1", "b_one"], ["b_num"]),
        mk("Slice", ["b_boxes", "b_minus1", "b_big", "b_one"], ["b_den"]),
        # num / den where den > 0, else 0
        mk("Greater", ["b_den", "b_fzero"], ["b_pos"]),
        mk("Where", ["b_pos", "b_den", "b_fone"], ["b_safe"]),
        mk("Div", ["b_num", "b_safe"], ["b_ratio"]),
        mk("Where", ["b_pos", "b_ratio", "b_fzero"], ["out_i"]),
        mk("Identity", ["cond_in"], ["cond_out"]),
    ]
    return helper.make_graph(
        nodes,
        "weight_sharing_filter_size",
        [
            helper.make_tensor_value_info("i", TensorProto.INT64, []),
            helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
        ],
        [
            helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
            helper.make_tensor_value_info("out_i", TensorProto.FLOAT, None),
        ],
    )


def _ones_value() -> onnx.TensorProto:
    return helper.make_tensor("", TensorProto.FLOAT, [1], [1.0])


@function_body("WeightSharingFilter")
def weight_sharing_filter_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.WeightSharingFilter in standard ops."""
    mk = helper.make_node
    return [
        attr_const("smin", "size_min"),
        attr_const("step", "size_step"),
        attr_const("count_", "count"),
        int_const("n_start", [0]),
        int_const("n_end", [1]),
        int_const("hw_start", [2]),
        int_const("hw_end", [4]),
        int_const("minus1_1", [-1, 1]),
        int_const("minus1", [-1]),
        mk("Shape", ["image"], ["shape"]),
        mk("Slice", ["shape", "n_start", "n_end"], ["n"]),
        mk("Slice", ["shape", "hw_start", "hw_end"], ["hw"]),
        mk("Concat", ["minus1_1", "hw"], ["plane_shape"], axis=0),
        mk("Loop", ["count_", ""], ["scan"], body=_loop_body()),  # (S, N, C, H, W)
        mk("Transpose", ["scan"], ["scan_t"], perm=[1, 0, 2, 3, 4]),
        mk("Concat", ["n", "minus1", "hw"], ["out_shape"], axis=0),
        mk("Reshape", ["scan_t", "out_shape"], ["output"]),
    ]
