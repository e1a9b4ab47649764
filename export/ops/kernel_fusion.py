"""ONNX form of KernelFusion (Fan21 kernel fusion); torch form: rtdenoise.models.ops.kernel_fusion.

Node: rtdenoise.KernelFusion(images (N,S*C,H,W), logits (N,S,H,W)) -> output (N,C,H,W); no
attributes (S from logits, C = channels(images) / S).
Function body: softmax over axis 1 of the logits (ReduceMax, Sub, Exp, ReduceSum, Div), images
reshaped to (N, S, C, H, W), Mul with the unsqueezed probabilities, ReduceSum over S.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper

from .base import OpSpec, int_const, make_function, make_op, make_schema

NAME = "KernelFusion"
INPUTS = ("images", "logits")
OUTPUTS = ("output",)
ATTRS: tuple[str, ...] = ()
DOC = "out[:, c] = sum_i softmax_i(logits)[i] * images[:, i*C + c], C = channels / S (Fan21)"

SCHEMA = make_schema(NAME, INPUTS, OUTPUTS, ATTRS, DOC)
_OP = make_op(SCHEMA)

EXAMPLE_SIZES = 6  # Fan21: six filtered images


def translation(images, logits):
    """torch.ops.rtdenoise.kernel_fusion -> one rtdenoise.KernelFusion node."""
    return _OP(images, logits)


def build_function(opset: int) -> onnx.FunctionProto:
    """Model-local FunctionProto rtdenoise.KernelFusion in standard ops."""
    mk = helper.make_node
    if opset >= 18:  # axes became an input of ReduceMax in opset 18
        reduce_max = mk("ReduceMax", ["logits", "one"], ["top"], keepdims=1)
    else:
        reduce_max = mk("ReduceMax", ["logits"], ["top"], axes=[1], keepdims=1)
    nodes = [
        int_const("zero", [0]),
        int_const("one", [1]),
        int_const("two", [2]),
        int_const("four", [4]),
        int_const("minus1", [-1]),
        # softmax over axis 1 spelled out: ORT's Softmax(axis=1) on NCHW transposes
        # internally and was 4x slower at 720p (400 ms vs 92 ms)
        reduce_max,
        mk("Sub", ["logits", "top"], ["shifted"]),
        mk("Exp", ["shifted"], ["e"]),
        mk("ReduceSum", ["e", "one"], ["total"], keepdims=1),
        mk("Div", ["e", "total"], ["p"]),
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
    return make_function(NAME, INPUTS, OUTPUTS, ATTRS, nodes, opset, DOC)


def example_inputs(
    shape: tuple[int, ...], attrs: dict, rng: np.random.Generator
) -> list[np.ndarray]:
    """images (N, 6*C, H, W) in [0, 1) and logits (N, 6, H, W) ~ 2 * normal, for an output
    shape (N, C, H, W)."""
    n, c, h, w = shape
    s = EXAMPLE_SIZES
    images = rng.random((n, s * c, h, w), dtype=np.float32)
    logits = (2.0 * rng.standard_normal((n, s, h, w), dtype=np.float32)).astype(np.float32)
    return [images, logits]


def output_shape(input_shapes: list[list], attrs: dict) -> list[list]:
    """[(N, C, H, W)] from images (N, S*C, H, W) and logits (N, S, H, W); C unnamed unless
    both channel counts are numbers."""
    (n, sc, h, w), s = input_shapes[0], input_shapes[1][1]
    both = isinstance(sc, int) and isinstance(s, int)
    return [[n, sc // s if both else None, h, w]]


SPEC = OpSpec(
    name=NAME,
    torch_name="kernel_fusion",
    inputs=INPUTS,
    outputs=OUTPUTS,
    int_attrs=ATTRS,
    schema=SCHEMA,
    translation=translation,
    build_function=build_function,
    example_inputs=example_inputs,
    output_shape=output_shape,
)
