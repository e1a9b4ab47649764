"""TemporalAccumulation as an ONNX function body; spec: rtdenoise.ops.temporal_accumulation.

Body: an If on the attribute per_tap, each branch the whole step (outputs renamed per branch,
the If gives the function's outputs), so a model runs only the reprojection it asked for:
- per_tap = 0 (bilinear): Reproject's body on the concatenated state (its clamped source
  positions give the in-bounds test too), then the validity test, the selection and the blend
  of `models.temporal.temporal_step`, node for node in the torch form's order (names of this
  part start with `ta_`; Reproject's are its own);
- per_tap = 1, 2 or 3 (an inner If on per_tap >= 2 picks one of two bodies):
  `models.temporal.per_tap_history` (names start with `tp_`): the four taps' positions and
  bilinear weights, per tap one GatherElements of the (N, C + 5, H*W) state and its inside /
  depth / normal tests (2 and 3: and its HDR averaging weight, whose divisor 3 squares by a
  select on per_tap == 3), the renormalisation, then the same blend.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from rtdenoise.ops.temporal_accumulation import HDR_FLOOR, HDR_RATIO

from .base import attr_const, float_const, function_body, if_branch, int_const
from .reproject import bilinear_nodes, sampling_grid

OUTPUTS = ("accumulated", "blend", "next_ta", "next_geometry")


def _in_bounds() -> list[onnx.NodeProto]:
    """ta_inside (N, 1, H, W): the unclamped previous position (Reproject's x_pos = x + mx,
    y_pos) within [-0.5, size - 0.5] on both axes."""
    mk = helper.make_node
    nodes = [float_const("ta_mhalf", -0.5), float_const("ta_half", 0.5)]
    tests = []
    for a, size in (("x", "w_f"), ("y", "h_f")):
        nodes += [
            mk("Sub", [size, "ta_half"], [f"ta_{a}_hi"]),
            mk("GreaterOrEqual", [f"{a}_pos", "ta_mhalf"], [f"ta_{a}_ge"]),
            mk("LessOrEqual", [f"{a}_pos", f"ta_{a}_hi"], [f"ta_{a}_le"]),
        ]
        tests += [f"ta_{a}_ge", f"ta_{a}_le"]
    nodes += [
        mk("And", tests[:2], ["ta_in_x"]),
        mk("And", ["ta_in_x", tests[2]], ["ta_in_xy"]),
        mk("And", ["ta_in_xy", tests[3]], ["ta_inside3"]),
        mk("Unsqueeze", ["ta_inside3", "one_i"], ["ta_inside"]),  # (N, 1, H, W)
    ]
    return nodes


def _blend() -> list[onnx.NodeProto]:
    """models.temporal.accumulate: ta_valid, ta_history, ta_history_len -> the outputs."""
    mk = helper.make_node
    return [
        mk("Greater", ["ta_valid", "ta_half"], ["ta_ok"]),
        mk("Where", ["ta_ok", "ta_history_len", "f0"], ["ta_n_prev"]),
        mk("Where", ["ta_ok", "ta_history", "f0"], ["ta_hist"]),
        mk("Add", ["ta_n_prev", "f1"], ["ta_n_next"]),
        mk("Div", ["f1", "ta_n_next"], ["ta_uniform"]),
        mk("Max", ["ta_uniform", "min_alpha"], ["blend"]),
        mk("Mul", ["blend", "current"], ["ta_new_part"]),
        mk("Sub", ["f1", "blend"], ["ta_keep_weight"]),
        mk("Mul", ["ta_keep_weight", "ta_hist"], ["ta_old_part"]),
        mk("Add", ["ta_new_part", "ta_old_part"], ["accumulated"]),
        mk("Min", ["ta_n_next", "max_history"], ["ta_new_len"]),
        mk("Concat", ["accumulated", "ta_new_len"], ["next_ta"], axis=1),
        mk("Concat", ["normal", "depth"], ["next_geometry"], axis=1),
    ]


def _bilinear_body(opset: int) -> list[onnx.NodeProto]:
    """per_tap = 0: the whole state warped by Reproject, its geometry tested per pixel."""
    mk = helper.make_node
    warp = [mk("Concat", ["ta_state", "geometry_state"], ["previous"], axis=1)]
    warp += bilinear_nodes(opset)  # previous, motion -> output (the warped state)
    channels = [
        mk("Shape", ["current"], ["ta_c"], start=1, end=2),  # [C]
        mk("Add", ["ta_c", "one_i"], ["ta_c1"]),
        mk("Add", ["ta_c", "four_i"], ["ta_c4"]),
        mk("Add", ["ta_c4", "one_i"], ["ta_c5"]),
        mk("Slice", ["output", "zero_i", "ta_c", "one_i"], ["ta_history"]),
        mk("Slice", ["output", "ta_c", "ta_c1", "one_i"], ["ta_history_len"]),
        mk("Slice", ["output", "ta_c1", "ta_c4", "one_i"], ["ta_prev_normal"]),
        mk("Slice", ["output", "ta_c4", "ta_c5", "one_i"], ["ta_prev_depth"]),
    ]
    validity = [  # models.temporal.history_validity
        mk("Sub", ["ta_prev_depth", "depth"], ["ta_depth_diff"]),
        mk("Abs", ["ta_depth_diff"], ["ta_depth_err"]),
        mk("Abs", ["depth"], ["ta_depth_abs"]),
        mk("Mul", ["depth_tolerance", "ta_depth_abs"], ["ta_depth_tol"]),
        mk("Less", ["ta_depth_err", "ta_depth_tol"], ["ta_depth_ok"]),
        mk("Mul", ["ta_prev_normal", "normal"], ["ta_normal_prod"]),
        mk("ReduceSum", ["ta_normal_prod", "one_i"], ["ta_normal_dot"], keepdims=1),
        mk("Greater", ["ta_normal_dot", "normal_threshold"], ["ta_normal_ok"]),
        mk("And", ["ta_inside", "ta_depth_ok"], ["ta_ok2"]),
        mk("And", ["ta_ok2", "ta_normal_ok"], ["ta_ok3"]),
        mk("Cast", ["ta_ok3"], ["ta_valid_geometry"], to=TensorProto.FLOAT),
        mk("Sub", ["f1", "reset"], ["ta_keep"]),
        mk("Mul", ["ta_valid_geometry", "ta_keep"], ["ta_valid"]),
    ]
    return warp + channels + _in_bounds() + validity + _blend()


TAPS = ("nw", "ne", "sw", "se")  # models.temporal.per_tap_history's order


def _tap_brightness(p: str) -> list[onnx.NodeProto]:
    """{p}_bright: max(mean of tap p's C accumulated channels, 0) (models.temporal.
    tap_brightness)."""
    mk = helper.make_node
    return [
        mk("Slice", [f"{p}_g", "zero_i", "ta_c", "one_i"], [f"{p}_colour"]),
        mk("ReduceSum", [f"{p}_colour", "one_i"], [f"{p}_sum"], keepdims=1),
        mk("Div", [f"{p}_sum", "tp_c_f"], [f"{p}_mean"]),
        mk("Max", [f"{p}_mean", "f0"], [f"{p}_bright"]),
    ]


def _outlier_bound() -> list[onnx.NodeProto]:
    """tp_bound: HDR_RATIO x the darkest accepted tap's brightness + HDR_FLOOR, the darkest
    folded in tap order from +inf by selects (models.temporal.outlier_bound)."""
    mk = helper.make_node
    nodes = [
        float_const("tp_inf", float("inf")),
        float_const("tp_ratio", HDR_RATIO),
        float_const("tp_floor", HDR_FLOOR),
    ]
    darkest = "tp_inf"
    for t in TAPS:
        p = f"tp_{t}"
        nodes += [
            mk("Less", [f"{p}_bright", darkest], [f"{p}_darker"]),
            mk("And", [f"{p}_ok", f"{p}_darker"], [f"{p}_darkest_so_far"]),
            mk("Where", [f"{p}_darkest_so_far", f"{p}_bright", darkest], [f"{p}_darkest"]),
        ]
        darkest = f"{p}_darkest"
    return nodes + [
        mk("Mul", ["tp_ratio", darkest], ["tp_scaled_darkest"]),
        mk("Add", ["tp_scaled_darkest", "tp_floor"], ["tp_bound"]),
    ]


def _hdr_weight(p: str, weight: str) -> list[onnx.NodeProto]:
    """{p}_aw: the accepted tap's weight / (1 + max(brightness - tp_bound, 0)), squared where
    ta_squared (per_tap 3), 0 where the tap is rejected."""
    mk = helper.make_node
    return [
        mk("Sub", [f"{p}_bright", "tp_bound"], [f"{p}_above"]),
        mk("Max", [f"{p}_above", "f0"], [f"{p}_excess"]),
        mk("Add", ["f1", f"{p}_excess"], [f"{p}_scale1"]),
        mk("Mul", [f"{p}_scale1", f"{p}_scale1"], [f"{p}_scale2"]),
        mk("Where", ["ta_squared", f"{p}_scale2", f"{p}_scale1"], [f"{p}_scale"]),
        mk("Div", [weight, f"{p}_scale"], [f"{p}_average"]),
        mk("Where", [f"{p}_ok", f"{p}_average", "f0"], [f"{p}_aw"]),
    ]


def _tap_tests(p: str, fx: str, fy: str, weight: str) -> list[onnx.NodeProto]:
    """One tap at the integer-valued float position (fx, fy) (N, H, W): its values gathered
    (position clamped into the image) {p}_g, its tests {p}_ok, its accepted weight {p}_w and
    state {p}_value (models.temporal.per_tap_history's first loop)."""
    mk = helper.make_node
    return [
        mk("GreaterOrEqual", [fx, "f0"], [f"{p}_gx"]),
        mk("LessOrEqual", [fx, "tp_x_max"], [f"{p}_lx"]),
        mk("GreaterOrEqual", [fy, "f0"], [f"{p}_gy"]),
        mk("LessOrEqual", [fy, "tp_y_max"], [f"{p}_ly"]),
        mk("And", [f"{p}_gx", f"{p}_lx"], [f"{p}_in1"]),
        mk("And", [f"{p}_in1", f"{p}_gy"], [f"{p}_in2"]),
        mk("And", [f"{p}_in2", f"{p}_ly"], [f"{p}_in3"]),
        mk("Unsqueeze", [f"{p}_in3", "one_i"], [f"{p}_inside"]),  # (N, 1, H, W)
        mk("Max", [fx, "f0"], [f"{p}_cx0"]),
        mk("Min", [f"{p}_cx0", "tp_x_max"], [f"{p}_cx"]),
        mk("Max", [fy, "f0"], [f"{p}_cy0"]),
        mk("Min", [f"{p}_cy0", "tp_y_max"], [f"{p}_cy"]),
        mk("Cast", [f"{p}_cx"], [f"{p}_ix"], to=TensorProto.INT64),
        mk("Cast", [f"{p}_cy"], [f"{p}_iy"], to=TensorProto.INT64),
        mk("Mul", [f"{p}_iy", "w_i"], [f"{p}_row"]),
        mk("Add", [f"{p}_row", f"{p}_ix"], [f"{p}_idx2"]),  # (N, H, W)
        mk("Reshape", [f"{p}_idx2", "idx_shape"], [f"{p}_idx1"]),  # (N, 1, H*W)
        mk("Expand", [f"{p}_idx1", "flat_dims"], [f"{p}_idx"]),  # (N, C + 5, H*W)
        mk("GatherElements", ["flat", f"{p}_idx"], [f"{p}_flat"], axis=2),
        mk("Reshape", [f"{p}_flat", "shape"], [f"{p}_g"]),  # (N, C + 5, H, W)
        mk("Slice", [f"{p}_g", "zero_i", "ta_c1", "one_i"], [f"{p}_state"]),
        mk("Slice", [f"{p}_g", "ta_c1", "ta_c4", "one_i"], [f"{p}_normal"]),
        mk("Slice", [f"{p}_g", "ta_c4", "ta_c5", "one_i"], [f"{p}_depth"]),
        mk("Sub", [f"{p}_depth", "depth"], [f"{p}_depth_diff"]),
        mk("Abs", [f"{p}_depth_diff"], [f"{p}_depth_err"]),
        mk("Less", [f"{p}_depth_err", "tp_depth_tol"], [f"{p}_depth_ok"]),
        mk("Mul", [f"{p}_normal", "normal"], [f"{p}_normal_prod"]),
        mk("ReduceSum", [f"{p}_normal_prod", "one_i"], [f"{p}_normal_dot"], keepdims=1),
        mk("Greater", [f"{p}_normal_dot", "normal_threshold"], [f"{p}_normal_ok"]),
        mk("And", [f"{p}_inside", f"{p}_depth_ok"], [f"{p}_ok2"]),
        mk("And", [f"{p}_ok2", f"{p}_normal_ok"], [f"{p}_ok"]),
        mk("Where", [f"{p}_ok", weight, "f0"], [f"{p}_w"]),
        mk("Where", [f"{p}_ok", f"{p}_state", "f0"], [f"{p}_value"]),
    ]


def _per_tap_body(opset: int, hdr: bool) -> list[onnx.NodeProto]:
    """per_tap = 1 (hdr False) or 2 and 3: models.temporal.per_tap_history, then the blend."""
    mk = helper.make_node
    base = [
        mk("Concat", ["ta_state", "geometry_state"], ["previous"], axis=1),
        *sampling_grid("previous", opset),  # flat: (N, C + 5, H*W)
        float_const("ta_half", 0.5),
        float_const("tp_cut", 0.01),
        mk("Sub", ["w_f", "f1"], ["tp_x_max"]),
        mk("Sub", ["h_f", "f1"], ["tp_y_max"]),
        mk("Shape", ["current"], ["ta_c"], start=1, end=2),  # [C]
        mk("Add", ["ta_c", "one_i"], ["ta_c1"]),
        mk("Add", ["ta_c", "four_i"], ["ta_c4"]),
        mk("Add", ["ta_c4", "one_i"], ["ta_c5"]),
        mk("Add", ["xs", "mx"], ["tp_px"]),
        mk("Add", ["ys", "my"], ["tp_py"]),
        mk("Floor", ["tp_px"], ["tp_x0"]),
        mk("Floor", ["tp_py"], ["tp_y0"]),
        mk("Add", ["tp_x0", "f1"], ["tp_x1"]),
        mk("Add", ["tp_y0", "f1"], ["tp_y1"]),
        mk("Sub", ["tp_px", "tp_x0"], ["tp_ax3"]),
        mk("Sub", ["tp_py", "tp_y0"], ["tp_ay3"]),
        mk("Unsqueeze", ["tp_ax3", "one_i"], ["tp_ax"]),  # (N, 1, H, W)
        mk("Unsqueeze", ["tp_ay3", "one_i"], ["tp_ay"]),
        mk("Sub", ["f1", "tp_ax"], ["tp_ex"]),
        mk("Sub", ["f1", "tp_ay"], ["tp_ey"]),
        mk("Mul", ["tp_ex", "tp_ey"], ["tp_k_nw"]),
        mk("Mul", ["tp_ax", "tp_ey"], ["tp_k_ne"]),
        mk("Mul", ["tp_ex", "tp_ay"], ["tp_k_sw"]),
        mk("Mul", ["tp_ax", "tp_ay"], ["tp_k_se"]),
        mk("Abs", ["depth"], ["tp_depth_abs"]),
        mk("Mul", ["depth_tolerance", "tp_depth_abs"], ["tp_depth_tol"]),
        *([mk("Cast", ["ta_c"], ["tp_c_f"], to=TensorProto.FLOAT)] if hdr else []),
    ]
    positions = {"nw": ("tp_x0", "tp_y0"), "ne": ("tp_x1", "tp_y0"),
                 "sw": ("tp_x0", "tp_y1"), "se": ("tp_x1", "tp_y1")}  # fmt: skip
    taps = [node for t in TAPS for node in _tap_tests(f"tp_{t}", *positions[t], f"tp_k_{t}")]
    weighed = "tp_total"  # the averaging weight: the cut's own unless hdr
    if hdr:
        taps += [node for t in TAPS for node in _tap_brightness(f"tp_{t}")]
        taps += _outlier_bound()
        taps += [node for t in TAPS for node in _hdr_weight(f"tp_{t}", f"tp_k_{t}")]
    for t in TAPS:
        p = f"tp_{t}"
        taps.append(mk("Mul", [f"{p}_aw" if hdr else f"{p}_w", f"{p}_value"], [f"{p}_part"]))
    if hdr:
        weighed = "tp_weighed"
        taps += [
            mk("Add", ["tp_nw_aw", "tp_ne_aw"], ["tp_weighed2"]),
            mk("Add", ["tp_weighed2", "tp_sw_aw"], ["tp_weighed3"]),
            mk("Add", ["tp_weighed3", "tp_se_aw"], ["tp_weighed"]),
        ]
    renormalise = [
        mk("Add", ["tp_nw_part", "tp_ne_part"], ["tp_acc2"]),
        mk("Add", ["tp_acc2", "tp_sw_part"], ["tp_acc3"]),
        mk("Add", ["tp_acc3", "tp_se_part"], ["tp_acc"]),
        mk("Add", ["tp_nw_w", "tp_ne_w"], ["tp_total2"]),
        mk("Add", ["tp_total2", "tp_sw_w"], ["tp_total3"]),
        mk("Add", ["tp_total3", "tp_se_w"], ["tp_total"]),
        mk("GreaterOrEqual", ["tp_total", "tp_cut"], ["tp_accepted"]),
        mk("Where", ["tp_accepted", weighed, "f1"], ["tp_denominator"]),
        mk("Div", ["tp_acc", "tp_denominator"], ["tp_warped"]),
        mk("Cast", ["tp_accepted"], ["tp_accepted_f"], to=TensorProto.FLOAT),
        mk("Sub", ["f1", "reset"], ["ta_keep"]),
        mk("Mul", ["tp_accepted_f", "ta_keep"], ["ta_valid"]),
        mk("Greater", ["ta_valid", "ta_half"], ["tp_ok"]),
        mk("Where", ["tp_ok", "tp_warped", "f0"], ["tp_selected"]),
        mk("Slice", ["tp_selected", "zero_i", "ta_c", "one_i"], ["ta_history"]),
        mk("Slice", ["tp_selected", "ta_c", "ta_c1", "one_i"], ["ta_history_len"]),
    ]
    return base + taps + renormalise + _blend()


def _branch(name: str, nodes: list[onnx.NodeProto]) -> onnx.GraphProto:
    """A subgraph of an If: `nodes` with the function's outputs renamed `<name>_<output>`."""
    return if_branch(f"temporal_accumulation_{name}", name, nodes, OUTPUTS)


@function_body("TemporalAccumulation")
def temporal_accumulation_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.TemporalAccumulation in standard ops: If(per_tap) [If(per_tap >= 2) per tap
    HDR-weighted (squared where per_tap == 3), else per tap], else bilinear."""
    mk = helper.make_node
    choose_weighting = mk(  # inside the per_tap branch, which renames its outputs
        "If",
        ["ta_hdr"],
        list(OUTPUTS),
        then_branch=_branch("hdr", _per_tap_body(opset, hdr=True)),
        else_branch=_branch("plain", _per_tap_body(opset, hdr=False)),
    )
    return [
        attr_const("ta_per_tap", "per_tap"),
        mk("Cast", ["ta_per_tap"], ["ta_per_tap_b"], to=TensorProto.BOOL),
        int_const("ta_one", 1),
        int_const("ta_three", 3),
        mk("Greater", ["ta_per_tap", "ta_one"], ["ta_hdr"]),
        mk("Equal", ["ta_per_tap", "ta_three"], ["ta_squared"]),
        mk(
            "If",
            ["ta_per_tap_b"],
            list(OUTPUTS),
            then_branch=_branch("per_tap", [choose_weighting]),
            else_branch=_branch("bilinear", _bilinear_body(opset)),
        ),
    ]
