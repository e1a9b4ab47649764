"""Reproject as an ONNX function body; spec: rtdenoise.ops.reproject.

Body: the pixel grid moved by the motion, normalised for align_corners = 0
(g = (2 p + 1) / size - 1), then GridSample (bilinear, border padding).
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import float_const, function_body, int_const


@function_body("Reproject")
def reproject_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.Reproject in standard ops (GridSample: opset 16+)."""
    mk = helper.make_node
    mode = "linear" if opset >= 20 else "bilinear"  # renamed in opset 20
    return [
        int_const("two_i", [2]),
        int_const("three_i", [3]),
        int_const("four_i", [4]),
        int_const("zero_i", [0]),
        int_const("one_i", [1]),
        int_const("minus1_i", [-1]),
        float_const("f0", 0.0),
        float_const("f1", 1.0),
        float_const("f2", 2.0),
        mk("Shape", ["motion"], ["shape"]),
        mk("Slice", ["shape", "two_i", "three_i"], ["h_i"]),
        mk("Slice", ["shape", "three_i", "four_i"], ["w_i"]),
        mk("Cast", ["h_i"], ["h_v"], to=TensorProto.FLOAT),
        mk("Cast", ["w_i"], ["w_v"], to=TensorProto.FLOAT),
        mk("Squeeze", ["h_v", "zero_i"], ["h"]),
        mk("Squeeze", ["w_v", "zero_i"], ["w"]),
        mk("Range", ["f0", "w", "f1"], ["xs"]),  # (W,)
        mk("Range", ["f0", "h", "f1"], ["ys0"]),  # (H,)
        mk("Unsqueeze", ["ys0", "one_i"], ["ys"]),  # (H, 1)
        mk("Split", ["motion"], ["mx4", "my4"], axis=1, num_outputs=2)
        if opset >= 18
        else mk("Split", ["motion"], ["mx4", "my4"], axis=1),
        mk("Squeeze", ["mx4", "one_i"], ["mx"]),  # (N, H, W)
        mk("Squeeze", ["my4", "one_i"], ["my"]),
        mk("Add", ["mx", "xs"], ["px"]),
        mk("Add", ["my", "ys"], ["py"]),
        # g = (2 p + 1) / size - 1
        mk("Mul", ["px", "f2"], ["px2"]),
        mk("Add", ["px2", "f1"], ["px21"]),
        mk("Div", ["px21", "w"], ["pxn"]),
        mk("Sub", ["pxn", "f1"], ["gx"]),
        mk("Mul", ["py", "f2"], ["py2"]),
        mk("Add", ["py2", "f1"], ["py21"]),
        mk("Div", ["py21", "h"], ["pyn"]),
        mk("Sub", ["pyn", "f1"], ["gy"]),
        mk("Unsqueeze", ["gx", "minus1_i"], ["gx1"]),
        mk("Unsqueeze", ["gy", "minus1_i"], ["gy1"]),
        mk("Concat", ["gx1", "gy1"], ["grid"], axis=-1),  # (N, H, W, 2)
        mk(
            "GridSample",
            ["previous", "grid"],
            ["output"],
            mode=mode,
            padding_mode="border",
            align_corners=0,
        ),
    ]
