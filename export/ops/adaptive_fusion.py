"""ONNX form of AdaptiveFusion (Lee24 eq. (3)); torch form: rtdenoise.models.ops.adaptive_fusion.

Node: rtdenoise.AdaptiveFusion(d_ta (N,C,H,W), d_low (N,C,H/2,W/2), alpha (N,1,H,W))
-> output (N,C,H,W); no attributes. H and W even.
Function body: out = d_ta + alpha * U(d_low - D(d_ta)), D = AveragePool 2x2 stride 2,
U = Resize nearest x2 (asymmetric, floor): eq. (3) with the two alpha terms merged.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper

from .base import OpSpec, make_function, make_op, make_schema

NAME = "AdaptiveFusion"
INPUTS = ("d_ta", "d_low", "alpha")
OUTPUTS = ("output",)
ATTRS: tuple[str, ...] = ()
DOC = (
    "out = d_ta - alpha * U(D(d_ta)) + alpha * U(d_low), D = 2x2 mean, U = nearest x2 (Lee24 eq. 3)"
)

SCHEMA = make_schema(NAME, INPUTS, OUTPUTS, ATTRS, DOC)
_OP = make_op(SCHEMA)


def translation(d_ta, d_low, alpha):
    """torch.ops.rtdenoise.adaptive_fusion -> one rtdenoise.AdaptiveFusion node."""
    return _OP(d_ta, d_low, alpha)


def build_function(opset: int) -> onnx.FunctionProto:
    """Model-local FunctionProto rtdenoise.AdaptiveFusion in standard ops."""
    mk = helper.make_node
    scales = helper.make_tensor("", TensorProto.FLOAT, [4], [1.0, 1.0, 2.0, 2.0])
    nodes = [
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
    return make_function(NAME, INPUTS, OUTPUTS, ATTRS, nodes, opset, DOC)


def example_inputs(
    shape: tuple[int, ...], attrs: dict, rng: np.random.Generator
) -> list[np.ndarray]:
    """d_ta (N, C, H, W), d_low (N, C, H/2, W/2) in [0, 1) and alpha (N, 1, H, W) in [0, 1)."""
    n, c, h, w = shape
    return [
        rng.random((n, c, h, w), dtype=np.float32),
        rng.random((n, c, h // 2, w // 2), dtype=np.float32),
        rng.random((n, 1, h, w), dtype=np.float32),
    ]


SPEC = OpSpec(
    name=NAME,
    torch_name="adaptive_fusion",
    inputs=INPUTS,
    outputs=OUTPUTS,
    int_attrs=ATTRS,
    schema=SCHEMA,
    translation=translation,
    build_function=build_function,
    example_inputs=example_inputs,
)
