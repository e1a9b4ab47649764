"""TemporalAccumulation as an ONNX function body; spec: rtdenoise.ops.temporal_accumulation.

Body: Reproject's body on the concatenated state (its clamped source positions give the
in-bounds test too), then the validity test, the selection and the blend of
`models.temporal.temporal_step`, node for node in the torch form's order (names of this body
start with `ta_`; Reproject's are its own).
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from .base import float_const, function_body
from .reproject import reproject_body


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


@function_body("TemporalAccumulation")
def temporal_accumulation_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.TemporalAccumulation in standard ops."""
    mk = helper.make_node
    warp = [mk("Concat", ["ta_state", "geometry_state"], ["previous"], axis=1)]
    warp += reproject_body.body(opset)  # previous, motion -> output (the warped state)
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
    blend = [  # models.temporal.accumulate
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
    return warp + channels + _in_bounds() + validity + blend
