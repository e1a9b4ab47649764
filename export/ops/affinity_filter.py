"""AffinityFilter as an ONNX function body (Isik21 eq. (4), (6)); defined in
rtdenoise.ops.affinity_filter.

Body: zero-Pad the image, the features and a ones mask by (k // 2) * dilation once, then a
`Loop` over the k * k taps (k read from the kernel_size input at run time, so one graph runs
at any k) accumulating the weighted image and the weights; the centre tap's weight is the
centre input; taps outside the image read mask 0. `affinity_sums` builds that loop for
TemporalAffinityFilter as well.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from rtdenoise.ops.affinity_filter import EPS

from .base import attr_const, float_const, function_body, int_const


def _tap_body(p: str, with_centre: bool) -> onnx.GraphProto:
    """One tap t of the loop `p`: num += w * image window, den += w, with
    w = exp(-bandwidth * ||f - other window||^2) * mask window (centre tap: the centre)."""
    mk = helper.make_node
    nodes = [
        int_const(f"{p}b_zero", [0]),
        int_const(f"{p}b_axes_hw", [2, 3]),
        int_const(f"{p}b_axis_c", [1]),
        mk("Div", ["t", f"{p}k"], [f"{p}b_i"]),
        mk("Mod", ["t", f"{p}k"], [f"{p}b_j"]),
        mk("Mul", [f"{p}b_i", f"{p}d"], [f"{p}b_sy"]),
        mk("Mul", [f"{p}b_j", f"{p}d"], [f"{p}b_sx"]),
        mk("Unsqueeze", [f"{p}b_sy", f"{p}b_zero"], [f"{p}b_sy1"]),
        mk("Unsqueeze", [f"{p}b_sx", f"{p}b_zero"], [f"{p}b_sx1"]),
        mk("Concat", [f"{p}b_sy1", f"{p}b_sx1"], [f"{p}b_starts"], axis=0),
        mk("Add", [f"{p}b_starts", f"{p}hw"], [f"{p}b_ends"]),
        mk("Slice", [f"{p}g_pad", f"{p}b_starts", f"{p}b_ends", f"{p}b_axes_hw"], [f"{p}b_g"]),
        mk("Slice", [f"{p}x_pad", f"{p}b_starts", f"{p}b_ends", f"{p}b_axes_hw"], [f"{p}b_x"]),
        mk("Slice", [f"{p}m_pad", f"{p}b_starts", f"{p}b_ends", f"{p}b_axes_hw"], [f"{p}b_m"]),
        mk("Sub", [f"{p}f", f"{p}b_g"], [f"{p}b_diff"]),
        mk("Mul", [f"{p}b_diff", f"{p}b_diff"], [f"{p}b_sq"]),
        mk("ReduceSum", [f"{p}b_sq", f"{p}b_axis_c"], [f"{p}b_dist"], keepdims=1),
        mk("Mul", [f"{p}neg_a", f"{p}b_dist"], [f"{p}b_arg"]),
        mk("Exp", [f"{p}b_arg"], [f"{p}b_e"]),
        mk("Mul", [f"{p}b_e", f"{p}b_m"], [f"{p}b_w"]),
    ]
    weight = f"{p}b_w"
    if with_centre:  # Isik21 eq. (4): the centre tap weighs c_p
        nodes += [
            mk("Equal", ["t", f"{p}t_centre"], [f"{p}b_is_c"]),
            mk("Where", [f"{p}b_is_c", f"{p}centre", f"{p}b_w"], [f"{p}b_wc"]),
        ]
        weight = f"{p}b_wc"
    nodes += [
        mk("Mul", [weight, f"{p}b_x"], [f"{p}b_term"]),
        mk("Add", ["num_in", f"{p}b_term"], ["num_out"]),
        mk("Add", ["den_in", weight], ["den_out"]),
        mk("Identity", ["cond_in"], ["cond_out"]),
    ]
    value = helper.make_tensor_value_info
    return helper.make_graph(
        nodes,
        f"{p}affinity_tap",
        [
            value("t", TensorProto.INT64, []),
            value("cond_in", TensorProto.BOOL, []),
            value("num_in", TensorProto.FLOAT, None),
            value("den_in", TensorProto.FLOAT, None),
        ],
        [
            value("cond_out", TensorProto.BOOL, []),
            value("num_out", TensorProto.FLOAT, None),
            value("den_out", TensorProto.FLOAT, None),
        ],
    )


def affinity_sums(
    p: str,
    image: str,
    features: str,
    other: str,
    bandwidth: str,
    size: str,
    dilation: str,
    mask: str | None = None,
    centre: str | None = None,
) -> list[onnx.NodeProto]:
    """Nodes computing `{p}num` = sum_q w_pq image_q and `{p}den` = sum_q w_pq over the
    size x size taps at `dilation` (int64 scalar name), w_pq = exp(-bandwidth_p ||features_p -
    other_q||^2) * mask_q (mask: ones inside the image, zero outside), centre tap = centre_p."""
    mk = helper.make_node
    ones = helper.make_tensor("", TensorProto.FLOAT, [1], [1.0])
    zero = helper.make_tensor("", TensorProto.FLOAT, [1], [0.0])
    nodes = [
        int_const(f"{p}two", 2),
        int_const(f"{p}zeros2", [0, 0]),
        int_const(f"{p}hw_start", [2]),
        int_const(f"{p}hw_end", [4]),
        int_const(f"{p}shape1", [1]),
        mk("Cast", [size], [f"{p}k"], to=TensorProto.INT64),
        mk("Identity", [dilation], [f"{p}d"]),
        mk("Div", [f"{p}k", f"{p}two"], [f"{p}r"]),
        mk("Mul", [f"{p}r", f"{p}d"], [f"{p}pad"]),
        mk("Reshape", [f"{p}pad", f"{p}shape1"], [f"{p}pad1"]),
        # pads = [0, 0, p, p, 0, 0, p, p] (begins of N, C, H, W, then ends)
        mk(
            "Concat",
            [f"{p}zeros2", f"{p}pad1", f"{p}pad1", f"{p}zeros2", f"{p}pad1", f"{p}pad1"],
            [f"{p}pads"],
            axis=0,
        ),
        mk("Identity", [features], [f"{p}f"]),
        mk("Pad", [image, f"{p}pads"], [f"{p}x_pad"], mode="constant"),
        mk("Pad", [other, f"{p}pads"], [f"{p}g_pad"], mode="constant"),
        mk("Shape", [bandwidth], [f"{p}shape_a"]),
    ]
    if mask is None:
        nodes.append(mk("ConstantOfShape", [f"{p}shape_a"], [f"{p}mask"], value=ones))
        mask = f"{p}mask"
    nodes += [
        mk("Pad", [mask, f"{p}pads"], [f"{p}m_pad"], mode="constant"),
        mk("Neg", [bandwidth], [f"{p}neg_a"]),
        mk("Shape", [image], [f"{p}shape"]),
        mk("Slice", [f"{p}shape", f"{p}hw_start", f"{p}hw_end"], [f"{p}hw"]),
        mk("ConstantOfShape", [f"{p}shape"], [f"{p}num0"], value=zero),
        mk("ConstantOfShape", [f"{p}shape_a"], [f"{p}den0"], value=zero),
        mk("Mul", [f"{p}k", f"{p}k"], [f"{p}taps"]),
    ]
    if centre is not None:
        nodes += [
            mk("Identity", [centre], [f"{p}centre"]),
            mk("Mul", [f"{p}r", f"{p}k"], [f"{p}rk"]),
            mk("Add", [f"{p}rk", f"{p}r"], [f"{p}t_centre"]),
        ]
    nodes.append(
        mk(
            "Loop",
            [f"{p}taps", "", f"{p}num0", f"{p}den0"],
            [f"{p}num", f"{p}den"],
            body=_tap_body(p, centre is not None),
        )
    )
    return nodes


@function_body("AffinityFilter")
def affinity_filter_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.AffinityFilter in standard ops."""
    mk = helper.make_node
    return [
        attr_const("dilation_value", "dilation"),
        *affinity_sums(
            "s_",
            "image",
            "features",
            "features",
            "bandwidth",
            "kernel_size",
            "dilation_value",
            centre="centre",
        ),  # fmt: skip
        float_const("eps", EPS),
        mk("Add", ["s_den", "eps"], ["den_eps"]),
        mk("Div", ["s_num", "den_eps"], ["output"]),
    ]
