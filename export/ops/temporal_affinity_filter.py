"""TemporalAffinityFilter as an ONNX function body (Isik21 eq. (7)-(8)); defined in
rtdenoise.ops.temporal_affinity_filter.

Body: AffinityFilter's tap loop twice (export.ops.affinity_filter.affinity_sums): the spatial
kernel over the image at the dilation with the centre weight, the temporal kernel over the
warped previous output at dilation 1 with the validity as mask; then one joint normalisation.
"""

from __future__ import annotations

import onnx
from onnx import helper

from rtdenoise.ops.affinity_filter import EPS

from .affinity_filter import affinity_sums
from .base import attr_const, float_const, function_body, int_const


@function_body("TemporalAffinityFilter")
def temporal_affinity_filter_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.TemporalAffinityFilter in standard ops."""
    mk = helper.make_node
    return [
        attr_const("dilation_value", "dilation"),
        int_const("one", 1),
        *affinity_sums(
            "s_",
            "image",
            "features",
            "features",
            "bandwidth",
            "kernel_size",
            "dilation_value",
            centre="centre",
        ),
        *affinity_sums(
            "t_",
            "previous",
            "features",
            "previous_features",
            "temporal_bandwidth",
            "temporal_size",
            "one",
            mask="valid",
        ),  # fmt: skip
        float_const("eps", EPS),
        mk("Add", ["s_num", "t_num"], ["num"]),
        mk("Add", ["s_den", "t_den"], ["den"]),
        mk("Add", ["den", "eps"], ["den_eps"]),
        mk("Div", ["num", "den_eps"], ["output"]),
    ]
