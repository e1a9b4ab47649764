"""Reproject as an ONNX function body; spec: rtdenoise.ops.reproject.

Body: an If on the attribute nearest, each branch from the clamped source position
p = clip(pixel + motion, 0, size - 1):
- bilinear (0): its floor and fraction, the flat indices of the four taps, four GatherElements
  on the (N, C, H*W) planes and the weighted sum nw (1 - wy)(1 - wx) + ne (1 - wy) wx +
  sw wy (1 - wx) + se wy wx: the torch form's arithmetic, node for node;
- nearest (1): floor(p + 0.5) on each axis and one GatherElements.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import attr_const, float_const, function_body, if_branch, int_const


def _tap(name: str, yi: str, xi: str) -> list[onnx.NodeProto]:
    """GatherElements of the flat (N, C, H*W) planes at yi * W + xi -> (N, C, H, W) `name`."""
    mk = helper.make_node
    return [
        mk("Mul", [yi, "w_i"], [f"{name}_row"]),
        mk("Add", [f"{name}_row", xi], [f"{name}_idx2"]),  # (N, H, W)
        mk("Reshape", [f"{name}_idx2", "idx_shape"], [f"{name}_idx1"]),  # (N, 1, H*W)
        mk("Expand", [f"{name}_idx1", "flat_dims"], [f"{name}_idx"]),  # (N, C, H*W)
        mk("GatherElements", ["flat", f"{name}_idx"], [f"{name}_flat"], axis=2),
        mk("Reshape", [f"{name}_flat", "shape"], [name]),
    ]


def _clamped_position(a: str, pixel: str, motion: str, size_f: str) -> list[onnx.NodeProto]:
    """The source position along one axis, a_pos = pixel + motion, clamped: a_p."""
    mk = helper.make_node
    return [
        mk("Sub", [size_f, "f1"], [f"{a}_max"]),
        mk("Add", [pixel, motion], [f"{a}_pos"]),
        mk("Max", [f"{a}_pos", "f0"], [f"{a}_lo"]),
        mk("Min", [f"{a}_lo", f"{a}_max"], [f"{a}_p"]),
    ]


def _axis_taps(a: str, pixel: str, motion: str, size_f: str, size_i: str) -> list:
    """Clamped position along one axis -> floor index a0, next index a1 and fraction wa."""
    mk = helper.make_node
    return [
        *_clamped_position(a, pixel, motion, size_f),
        mk("Floor", [f"{a}_p"], [f"{a}_floor"]),
        mk("Sub", [f"{a}_p", f"{a}_floor"], [f"w{a}"]),
        mk("Cast", [f"{a}_floor"], [f"{a}0"], to=TensorProto.INT64),
        mk("Sub", [size_i, "i1"], [f"{a}_last"]),
        mk("Add", [f"{a}0", "i1"], [f"{a}_next"]),
        mk("Min", [f"{a}_next", f"{a}_last"], [f"{a}1"]),
    ]


def sampling_grid(state: str, opset: int) -> list[onnx.NodeProto]:
    """The nodes every warp of `state` (N, C, H, W) by `motion` starts with: the shape ("shape",
    "n", "nc", "h_i"/"w_i" and their floats), the flat planes "flat" (N, C, H*W) with
    "flat_dims", the index shape "idx_shape" (N, 1, -1), the pixel grid "xs" (W,) / "ys"
    (H, 1), the motion planes "mx" / "my" (N, H, W) and the constants they use."""
    mk = helper.make_node
    return [
        int_const("zero_i", [0]),
        int_const("one_i", [1]),
        int_const("two_i", [2]),
        int_const("three_i", [3]),
        int_const("four_i", [4]),
        int_const("minus1_i", [-1]),
        float_const("f0", 0.0),
        float_const("f1", 1.0),
        mk("Shape", [state], ["shape"]),
        mk("Slice", ["shape", "zero_i", "two_i"], ["nc"]),
        mk("Slice", ["shape", "zero_i", "one_i"], ["n"]),
        mk("Slice", ["shape", "two_i", "three_i"], ["h1"]),
        mk("Slice", ["shape", "three_i", "four_i"], ["w1"]),
        mk("Squeeze", ["h1", "zero_i"], ["h_i"]),
        mk("Squeeze", ["w1", "zero_i"], ["w_i"]),
        mk("Cast", ["h_i"], ["h_f"], to=TensorProto.FLOAT),
        mk("Cast", ["w_i"], ["w_f"], to=TensorProto.FLOAT),
        mk("Concat", ["nc", "minus1_i"], ["flat_shape"], axis=0),  # (N, C, -1)
        mk("Reshape", [state, "flat_shape"], ["flat"]),
        mk("Shape", ["flat"], ["flat_dims"]),
        mk("Concat", ["n", "one_i", "minus1_i"], ["idx_shape"], axis=0),  # (N, 1, -1)
        mk("Range", ["f0", "w_f", "f1"], ["xs"]),  # (W,)
        mk("Range", ["f0", "h_f", "f1"], ["ys0"]),
        mk("Unsqueeze", ["ys0", "one_i"], ["ys"]),  # (H, 1)
        mk("Split", ["motion"], ["mx4", "my4"], axis=1, num_outputs=2)
        if opset >= 18
        else mk("Split", ["motion"], ["mx4", "my4"], axis=1),
        mk("Squeeze", ["mx4", "one_i"], ["mx"]),  # (N, H, W)
        mk("Squeeze", ["my4", "one_i"], ["my"]),
    ]


def _nearest_axis(a: str, pixel: str, motion: str, size_f: str) -> list[onnx.NodeProto]:
    """The clamped position along one axis rounded to the nearest pixel -> int64 index a0."""
    mk = helper.make_node
    return [
        *_clamped_position(a, pixel, motion, size_f),
        mk("Add", [f"{a}_p", "f_half"], [f"{a}_round"]),
        mk("Floor", [f"{a}_round"], [f"{a}_floor"]),
        mk("Cast", [f"{a}_floor"], [f"{a}0"], to=TensorProto.INT64),
    ]


def nearest_nodes(opset: int) -> list[onnx.NodeProto]:
    """previous, motion -> output: the nearest pixel of the clamped source position."""
    return [
        *sampling_grid("previous", opset),
        float_const("f_half", 0.5),
        *_nearest_axis("x", "xs", "mx", "w_f"),
        *_nearest_axis("y", "ys", "my", "h_f"),
        *_tap("nearest", "y0", "x0"),
        helper.make_node("Identity", ["nearest"], ["output"]),
    ]


def bilinear_nodes(opset: int) -> list[onnx.NodeProto]:
    """previous, motion -> output: the bilinear sample (TemporalAccumulation's warp too)."""
    mk = helper.make_node
    return [
        *sampling_grid("previous", opset),
        int_const("i1", 1),
        *_axis_taps("x", "xs", "mx", "w_f", "w_i"),
        *_axis_taps("y", "ys", "my", "h_f", "h_i"),
        *_tap("nw", "y0", "x0"),
        *_tap("ne", "y0", "x1"),
        *_tap("sw", "y1", "x0"),
        *_tap("se", "y1", "x1"),
        mk("Unsqueeze", ["wx", "one_i"], ["wx4"]),  # (N, 1, H, W)
        mk("Unsqueeze", ["wy", "one_i"], ["wy4"]),
        mk("Sub", ["f1", "wx4"], ["ex4"]),
        mk("Sub", ["f1", "wy4"], ["ey4"]),
        mk("Mul", ["ey4", "ex4"], ["k_nw"]),
        mk("Mul", ["ey4", "wx4"], ["k_ne"]),
        mk("Mul", ["wy4", "ex4"], ["k_sw"]),
        mk("Mul", ["wy4", "wx4"], ["k_se"]),
        mk("Mul", ["nw", "k_nw"], ["t_nw"]),
        mk("Mul", ["ne", "k_ne"], ["t_ne"]),
        mk("Mul", ["sw", "k_sw"], ["t_sw"]),
        mk("Mul", ["se", "k_se"], ["t_se"]),
        mk("Add", ["t_nw", "t_ne"], ["s1"]),
        mk("Add", ["s1", "t_sw"], ["s2"]),
        mk("Add", ["s2", "t_se"], ["output"]),
    ]


@function_body("Reproject")
def reproject_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.Reproject in standard ops: If(nearest) nearest, else bilinear."""
    mk = helper.make_node
    return [
        attr_const("rp_nearest", "nearest"),
        mk("Cast", ["rp_nearest"], ["rp_nearest_b"], to=TensorProto.BOOL),
        mk(
            "If",
            ["rp_nearest_b"],
            ["output"],
            then_branch=if_branch("reproject_nearest", "nearest", nearest_nodes(opset), ["output"]),
            else_branch=if_branch(
                "reproject_bilinear", "bilinear", bilinear_nodes(opset), ["output"]
            ),
        ),
    ]
