"""BilateralGrid as an ONNX function body (Meng20); defined in rtdenoise.ops.bilateral_grid.

Body: per axis, the two cells around each position (Floor, the tent max(1 - sqrt(u^2 + eps), 0),
a 0/1 mask for cells outside the grid, indices clamped); the 8 corners' flat cell indices
((iy * Gw + ix) * D + iz) and weights are concatenated to (N, 8 HW). Splat: one
ScatterElements(reduction="add") of [T * image, T] into zeros (N, C + 1, Gh*Gw*D), then
sum / weight sum where the weight sum is positive. Slice: one GatherElements of
[mean, filled] at the same indices, ReduceSum over the 8 corners of T * filled * mean and of
T * filled, and their ratio. Gh, Gw = ceil(H / s), ceil(W / s) from the dynamic shape.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from rtdenoise.ops.bilateral_grid import GUIDE_MAX, GUIDE_RANGE, TENT_EPS

from .base import attr_const, float_const, function_body, int_const


def _axis(p: str, pos: str, cells: str, cells_m1: str) -> list[onnx.NodeProto]:
    """Nodes for the two cells around `pos` on one axis: `{p}_i{k}` (int64 index clamped to
    [0, cells - 1]) and `{p}_w{k}` (tent weight, 0 outside the grid), k = 0, 1."""
    mk = helper.make_node
    nodes = [
        mk("Sub", [pos, "half"], [f"{p}_t"]),
        mk("Floor", [f"{p}_t"], [f"{p}_f"]),
        mk("Sub", [f"{p}_t", f"{p}_f"], [f"{p}_u0"]),
        mk("Sub", [f"{p}_u0", "fone"], [f"{p}_u1"]),
        mk("Cast", [f"{p}_f"], [f"{p}_j0"], to=TensorProto.INT64),
        mk("Add", [f"{p}_j0", "one_s"], [f"{p}_j1"]),
    ]
    for k in (0, 1):
        u, j = f"{p}_u{k}", f"{p}_j{k}"
        nodes += [
            # T(u) = max(1 - sqrt(u^2 + eps), 0) (Meng20 eq. (9))
            mk("Mul", [u, u], [f"{p}_sq{k}"]),
            mk("Add", [f"{p}_sq{k}", "eps"], [f"{p}_sqe{k}"]),
            mk("Sqrt", [f"{p}_sqe{k}"], [f"{p}_abs{k}"]),
            mk("Sub", ["fone", f"{p}_abs{k}"], [f"{p}_lin{k}"]),
            mk("Max", [f"{p}_lin{k}", "fzero"], [f"{p}_tent{k}"]),
            # cells outside the grid get weight 0
            mk("GreaterOrEqual", [j, "zero_s"], [f"{p}_ge{k}"]),
            mk("Less", [j, cells], [f"{p}_lt{k}"]),
            mk("And", [f"{p}_ge{k}", f"{p}_lt{k}"], [f"{p}_in{k}"]),
            mk("Cast", [f"{p}_in{k}"], [f"{p}_inf{k}"], to=TensorProto.FLOAT),
            mk("Mul", [f"{p}_tent{k}", f"{p}_inf{k}"], [f"{p}_w{k}"]),
            mk("Max", [j, "zero_s"], [f"{p}_jc{k}"]),
            mk("Min", [f"{p}_jc{k}", cells_m1], [f"{p}_i{k}"]),
        ]
    return nodes


def _positions() -> list[onnx.NodeProto]:
    """py (H, 1), px (1, W): (i + 0.5) / s; pz (N, 1, H, W): (clamp(g, 0, 255) + 0.5) D / 256."""
    mk = helper.make_node
    nodes = []
    for name, size, axis in (("py", "h1", [1]), ("px", "w1", [0])):
        nodes += [
            mk("Squeeze", [size, "zero"], [f"{name}_n"]),
            mk("Range", ["zero_s", f"{name}_n", "one_s"], [f"{name}_ii"]),
            mk("Cast", [f"{name}_ii"], [f"{name}_if"], to=TensorProto.FLOAT),
            mk("Add", [f"{name}_if", "half"], [f"{name}_c"]),
            mk("Div", [f"{name}_c", "s_f"], [f"{name}_1d"]),
            int_const(f"{name}_axis", axis),
            mk("Unsqueeze", [f"{name}_1d", f"{name}_axis"], [name]),
        ]
    nodes += [
        mk("Clip", ["guide", "fzero", "gmax"], ["g_clamped"]),
        mk("Add", ["g_clamped", "half"], ["g_c"]),
        mk("Mul", ["g_c", "d_f"], ["g_cd"]),
        mk("Div", ["g_cd", "grange"], ["pz"]),  # Meng20 eq. (12)
    ]
    return nodes


def _corners() -> list[onnx.NodeProto]:
    """idx8 / w8 (N, 1, 8, HW): flat cell index (iy * Gw + ix) * D + iz and weight
    wy * wx * wz of the 8 corners, corner-major."""
    mk = helper.make_node
    nodes, idx, wts = [], [], []
    for a in (0, 1):
        for b in (0, 1):
            ab = f"c{a}{b}"
            nodes += [
                mk("Mul", [f"y_i{a}", "gw1"], [f"{ab}_row"]),
                mk("Add", [f"{ab}_row", f"x_i{b}"], [f"{ab}_cell"]),
                mk("Mul", [f"{ab}_cell", "d_i"], [f"{ab}_base"]),
                mk("Mul", [f"y_w{a}", f"x_w{b}"], [f"{ab}_wxy"]),
            ]
            for c in (0, 1):
                abc = f"{ab}{c}"
                nodes += [
                    mk("Add", [f"{ab}_base", f"z_i{c}"], [f"{abc}_idx"]),
                    mk("Mul", [f"{ab}_wxy", f"z_w{c}"], [f"{abc}_w"]),
                ]
                idx.append(f"{abc}_idx")
                wts.append(f"{abc}_w")
    nodes += [
        mk("Concat", idx, ["idx8_nchw"], axis=1),  # (N, 8, H, W)
        mk("Concat", wts, ["w8_nchw"], axis=1),
        mk("Concat", ["n1", "one", "eight", "minus1"], ["shape_n18"], axis=0),
        mk("Reshape", ["idx8_nchw", "shape_n18"], ["idx8"]),
        mk("Reshape", ["w8_nchw", "shape_n18"], ["w8"]),
    ]
    return nodes


@function_body("BilateralGrid")
def bilateral_grid_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.BilateralGrid in standard ops."""
    mk = helper.make_node
    return [
        attr_const("s_i", "cell_size"),
        attr_const("d_i", "grid_depth"),
        mk("Cast", ["s_i"], ["s_f"], to=TensorProto.FLOAT),
        mk("Cast", ["d_i"], ["d_f"], to=TensorProto.FLOAT),
        int_const("zero", [0]),
        int_const("one", [1]),
        int_const("two", [2]),
        int_const("three", [3]),
        int_const("four", [4]),
        int_const("eight", [8]),
        int_const("minus1", [-1]),
        int_const("big", [2**62]),
        int_const("zero_s", 0),
        int_const("one_s", 1),
        float_const("half", 0.5),
        float_const("fone", 1.0),
        float_const("fzero", 0.0),
        float_const("eps", TENT_EPS),
        float_const("gmax", GUIDE_MAX),
        float_const("grange", GUIDE_RANGE),
        # sizes: N, C, H, W and the grid Gh = ceil(H / s), Gw = ceil(W / s), D (Meng20 eq. (8))
        mk("Shape", ["image"], ["shape"]),
        mk("Slice", ["shape", "zero", "one"], ["n1"]),
        mk("Slice", ["shape", "one", "two"], ["c1"]),
        mk("Slice", ["shape", "two", "three"], ["h1"]),
        mk("Slice", ["shape", "three", "four"], ["w1"]),
        mk("Sub", ["s_i", "one_s"], ["s_m1"]),
        mk("Add", ["h1", "s_m1"], ["h_up"]),
        mk("Div", ["h_up", "s_i"], ["gh1"]),
        mk("Add", ["w1", "s_m1"], ["w_up"]),
        mk("Div", ["w_up", "s_i"], ["gw1"]),
        mk("Sub", ["gh1", "one_s"], ["gh_m1"]),
        mk("Sub", ["gw1", "one_s"], ["gw_m1"]),
        mk("Sub", ["d_i", "one_s"], ["d_m1"]),
        *_positions(),
        *_axis("y", "py", "gh1", "gh_m1"),
        *_axis("x", "px", "gw1", "gw_m1"),
        *_axis("z", "pz", "d_i", "d_m1"),
        *_corners(),
        # splat (Meng20 eqs. (10)-(11)): scatter-add [T * image, T], divide by the weight sum
        mk("Add", ["c1", "one"], ["c1p"]),
        mk("Mul", ["h1", "w1"], ["hw1"]),
        mk("Concat", ["n1", "c1", "one", "minus1"], ["shape_img"], axis=0),
        mk("Reshape", ["image", "shape_img"], ["img4"]),  # (N, C, 1, HW)
        mk("Mul", ["img4", "w8"], ["weighted"]),  # (N, C, 8, HW)
        mk("Concat", ["weighted", "w8"], ["updates4"], axis=1),
        mk("Concat", ["n1", "c1p", "minus1"], ["shape_flat"], axis=0),
        mk("Reshape", ["updates4", "shape_flat"], ["updates"]),  # (N, C + 1, 8 HW)
        mk("Concat", ["n1", "c1p", "eight", "hw1"], ["shape_expand"], axis=0),
        mk("Expand", ["idx8", "shape_expand"], ["idx_expanded"]),
        mk("Reshape", ["idx_expanded", "shape_flat"], ["indices"]),
        mk("Mul", ["gh1", "gw1"], ["ghw"]),
        mk("Mul", ["ghw", "d_i"], ["cells1"]),
        mk("Concat", ["n1", "c1p", "cells1"], ["shape_grid"], axis=0),
        mk(
            "ConstantOfShape",
            ["shape_grid"],
            ["grid_zero"],
            value=helper.make_tensor("", TensorProto.FLOAT, [1], [0.0]),
        ),
        mk(
            "ScatterElements",
            ["grid_zero", "indices", "updates"],
            ["sums"],
            axis=2,
            reduction="add",
        ),
        mk("Slice", ["sums", "zero", "c1", "one"], ["sum_image"]),
        mk("Slice", ["sums", "c1", "big", "one"], ["sum_weight"]),
        mk("Greater", ["sum_weight", "fzero"], ["filled"]),
        mk("Where", ["filled", "sum_weight", "fone"], ["sum_safe"]),
        mk("Div", ["sum_image", "sum_safe"], ["ratio"]),
        mk("Where", ["filled", "ratio", "fzero"], ["mean"]),
        # slice (Meng20 eq. (13)): the same corners, renormalised over non-empty cells
        mk("Cast", ["filled"], ["filled_f"], to=TensorProto.FLOAT),
        mk("Concat", ["mean", "filled_f"], ["cells"], axis=1),
        mk("GatherElements", ["cells", "indices"], ["read"], axis=2),
        mk("Concat", ["n1", "c1p", "eight", "minus1"], ["shape_read"], axis=0),
        mk("Reshape", ["read", "shape_read"], ["read4"]),  # (N, C + 1, 8, HW)
        mk("Slice", ["read4", "zero", "c1", "one"], ["read_mean"]),
        mk("Slice", ["read4", "c1", "big", "one"], ["read_filled"]),
        mk("Mul", ["w8", "read_filled"], ["w_used"]),
        mk("Mul", ["w_used", "read_mean"], ["w_mean"]),
        mk("ReduceSum", ["w_mean", "two"], ["num"], keepdims=0),  # (N, C, HW)
        mk("ReduceSum", ["w_used", "two"], ["den"], keepdims=0),  # (N, 1, HW)
        mk("Greater", ["den", "fzero"], ["ok"]),
        mk("Where", ["ok", "den", "fone"], ["den_safe"]),
        mk("Div", ["num", "den_safe"], ["quotient"]),
        mk("Where", ["ok", "quotient", "fzero"], ["out_flat"]),
        mk("Reshape", ["out_flat", "shape"], ["output"]),
    ]
