"""ONNX form of KernelApply (Lee24 eq. (2)); torch form: rtdenoise.models.ops.kernel_apply.

Node: rtdenoise.KernelApply(image (N,C,H,W), kernel (N,k*k,H,W)) -> output (N,C,H,W),
attributes kernel_size (odd k) and dilation (>= 1), both required on every node.
Function body: edge-Pad once, then a Loop over the k*k taps accumulating
kernel[:, t] * shifted window (works for any k, dilation and dynamic H, W).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from .base import OpSpec, attr_const, int_const, make_function, make_op, make_schema

NAME = "KernelApply"
INPUTS = ("image", "kernel")
OUTPUTS = ("output",)
ATTRS = ("kernel_size", "dilation")
DOC = (
    "out[n,c,y,x] = sum_{i,j<k} kernel[n,i*k+j,y,x] * image[n,c,clamp(y+(i-k//2)*d),"
    " clamp(x+(j-k//2)*d)] (Lee24 eq. 2)"
)

SCHEMA = make_schema(NAME, INPUTS, OUTPUTS, ATTRS, DOC)
_OP = make_op(SCHEMA)


def translation(image, kernel, kernel_size: int, dilation: int):
    """torch.ops.rtdenoise.kernel_apply -> one rtdenoise.KernelApply node."""
    return _OP(image, kernel, kernel_size=kernel_size, dilation=dilation)


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


def build_function(opset: int) -> onnx.FunctionProto:
    """Model-local FunctionProto rtdenoise.KernelApply in standard ops."""
    mk = helper.make_node
    nodes = [
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
    return make_function(NAME, INPUTS, OUTPUTS, ATTRS, nodes, opset, DOC)


def example_inputs(
    shape: tuple[int, ...], attrs: dict, rng: np.random.Generator
) -> list[np.ndarray]:
    """image (N, C, H, W) in [0, 1) and a softmax-normalised kernel (N, k*k, H, W)."""
    n, _, h, w = shape
    k = attrs["kernel_size"]
    image = rng.random(shape, dtype=np.float32)
    logits = rng.standard_normal((n, k * k, h, w), dtype=np.float32)
    kernel = np.exp(logits - logits.max(axis=1, keepdims=True))
    kernel /= kernel.sum(axis=1, keepdims=True)
    return [image, kernel.astype(np.float32)]


SPEC = OpSpec(
    name=NAME,
    torch_name="kernel_apply",
    inputs=INPUTS,
    outputs=OUTPUTS,
    int_attrs=ATTRS,
    schema=SCHEMA,
    translation=translation,
    build_function=build_function,
    example_inputs=example_inputs,
    default_attrs={"kernel_size": 7, "dilation": 1},
)
