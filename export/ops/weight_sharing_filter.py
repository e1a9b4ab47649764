"""ONNX form of WeightSharingFilter (Fan21); torch form: rtdenoise.models.ops.weight_sharing_filter.

Node: rtdenoise.WeightSharingFilter(image (N,C,H,W), weights (N,S,H,W)) -> output (N,S*C,H,W),
attributes size_min (odd), size_step (even), count (= S), all required on every node; box size
i is size_min + i*size_step. ONNX Runtime extension ops take no list attributes, hence three
ints instead of a `sizes` list.

Function body: a Loop over the sizes. Iteration i stacks [w_i * image, w_i] as (N*(C+1), 1, H, W)
planes, zero-Pads them by s//2 and box-sums them with two Convs against all-ones 1 x s and
s x 1 kernels built at run time (ConstantOfShape: kernel size from the attributes, H and W
dynamic), then divides (Where: 0 where the weight sum is not positive). The scan output
(S, N, C, H, W) is transposed and reshaped to (N, S*C, H, W).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from .base import OpSpec, attr_const, int_const, make_function, make_op, make_schema

NAME = "WeightSharingFilter"
INPUTS = ("image", "weights")
OUTPUTS = ("output",)
ATTRS = ("size_min", "size_step", "count")
DOC = (
    "out[:, i*C:(i+1)*C] = boxsum_s(w_i * image) / boxsum_s(w_i) (0 where boxsum_s(w_i) <= 0), "
    "s = size_min + i*size_step, zero-padded s x s boxes (Fan21 weight-sharing kernels)"
)

SCHEMA = make_schema(NAME, INPUTS, OUTPUTS, ATTRS, DOC)
_OP = make_op(SCHEMA)


def translation(image, weights, size_min: int, size_step: int, count: int):
    """torch.ops.rtdenoise.weight_sharing_filter -> one rtdenoise.WeightSharingFilter node."""
    return _OP(image, weights, size_min=size_min, size_step=size_step, count=count)


def _float_const(name: str, value: float) -> onnx.NodeProto:
    return helper.make_node(
        "Constant", [], [name], value=helper.make_tensor("", TensorProto.FLOAT, [], [value])
    )


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
        _float_const("b_fzero", 0.0),
        _float_const("b_fone", 1.0),
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


def build_function(opset: int) -> onnx.FunctionProto:
    """Model-local FunctionProto rtdenoise.WeightSharingFilter in standard ops."""
    mk = helper.make_node
    nodes = [
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
    return make_function(NAME, INPUTS, OUTPUTS, ATTRS, nodes, opset, DOC)


def example_inputs(
    shape: tuple[int, ...], attrs: dict, rng: np.random.Generator
) -> list[np.ndarray]:
    """image (N, C, H, W) in [0, 1) and importance maps exp(2 * normal) > 0 (N, count, H, W)."""
    n, _, h, w = shape
    image = rng.random(shape, dtype=np.float32)
    weights = np.exp(2.0 * rng.standard_normal((n, attrs["count"], h, w), dtype=np.float32))
    return [image, weights.astype(np.float32)]


def output_shape(input_shapes: list[list], attrs: dict) -> list[list]:
    """[(N, count*C, H, W)] from the image shape (N, C, H, W); C*count unnamed if C is."""
    n, c, h, w = input_shapes[0]
    return [[n, c * attrs["count"] if isinstance(c, int) else None, h, w]]


SPEC = OpSpec(
    name=NAME,
    torch_name="weight_sharing_filter",
    inputs=INPUTS,
    outputs=OUTPUTS,
    int_attrs=ATTRS,
    schema=SCHEMA,
    translation=translation,
    build_function=build_function,
    example_inputs=example_inputs,
    default_attrs={"size_min": 3, "size_step": 2, "count": 6},
    output_shape=output_shape,
)
