"""CrossBilateralFilter as an ONNX function body (Choi24 eq. (9)); defined in
rtdenoise.ops.cross_bilateral_filter.

Body: mirrored padding of [pilot_a, pilot_b, albedo, normal] by Gather with reflected indices,
then a Loop over the window^2 taps; tap (dy, dx) slices the padded stack, forms the squared
distances and both weights m^A, m^B, and adds m f, m and m D_k f, m D_k to the four carried
sums.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from ._graph import FLOAT, INT64, Graph
from .base import attr_const, function_body
from .cross_regression import _mirror_index, _scalar


def _sq_dist(g: Graph, d2: str, start: int) -> str:
    return g.op("ReduceSum", g.slice(d2, start, start + 3, 1), g.ints(1), keepdims=1)


def _tap_body() -> onnx.GraphProto:
    """Tap t = (dy, dx): every sum += its term."""
    g = Graph("tap")
    dy = g.op("Div", "t", "k_win")
    dx = g.op("Mod", "t", "k_win")
    starts = g.op("Concat", g.unsqueeze(dy, 0), g.unsqueeze(dx, 0), axis=0)
    tap = g.op("Slice", "padded", starts, g.op("Add", starts, "hw"), g.ints(2, 3))
    d = g.op("Sub", tap, "centre")
    d2 = g.op("Mul", d, d)
    dist_rho, dist_n = _sq_dist(g, d2, 6), _sq_dist(g, d2, 9)
    oy, ox = g.op("Sub", dy, "r"), g.op("Sub", dx, "r")
    pos = g.op("Cast", g.op("Add", g.op("Mul", oy, oy), g.op("Mul", ox, ox)), to=FLOAT)
    dist_p = g.op("Div", pos, "r2")
    shared = g.op(
        "Add",
        g.op("Add", g.op("Mul", "band_rho", dist_rho), g.op("Mul", "band_n", dist_n)),
        g.op("Mul", "band_p", dist_p),
    )
    for key, start, band in (("a", 0, "band_a"), ("b", 3, "band_b")):
        f = g.slice(tap, start, start + 3, 1)
        dist_f = _sq_dist(g, d2, start)
        m = g.op("Exp", g.op("Neg", g.op("Add", g.op("Mul", band, dist_f), shared)))
        term = g.op("Concat", g.op("Mul", m, f), m, axis=1)  # (B, 4, H, W)
        g.op("Add", f"sum_{key}_in", term, out=f"sum_{key}_out")
        dterms = [g.op("Mul", term, dist) for dist in (dist_f, dist_rho, dist_n, dist_p)]
        g.op("Add", f"dsum_{key}_in", g.op("Concat", *dterms, axis=1), out=f"dsum_{key}_out")
    g.op("Identity", "cond_in", out="cond_out")
    carried = ("sum_a", "sum_b", "dsum_a", "dsum_b")
    return helper.make_graph(
        g.nodes,
        "cross_bilateral_tap",
        [
            helper.make_tensor_value_info("t", INT64, []),
            helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
            *(helper.make_tensor_value_info(f"{c}_in", FLOAT, None) for c in carried),
        ],
        [
            helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
            *(helper.make_tensor_value_info(f"{c}_out", FLOAT, None) for c in carried),
        ],
    )


@function_body("CrossBilateralFilter")
def cross_bilateral_filter_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.CrossBilateralFilter in standard ops (see the module docstring)."""
    g = Graph("cbf")
    g.node(attr_const("k_win", "window"))
    g.op("Div", "k_win", g.const(2, INT64), out="r")
    r_f = g.op("Cast", "r", to=FLOAT)
    g.op("Mul", r_f, r_f, out="r2")
    g.op("Concat", "pilot_a", "pilot_b", "albedo", "normal", axis=1, out="centre")
    for k, name in enumerate(("band_a", "band_b", "band_rho", "band_n", "band_p")):
        g.op("Slice", "band", g.ints(k), g.ints(k + 1), g.ints(1), out=name)
    shape = g.op("Shape", "pilot_a")
    g.op("Slice", shape, g.ints(2), g.ints(4), out="hw")
    padded = g.op("Gather", "centre", _mirror_index(g, _scalar(g, shape, 2), "r"), axis=2)
    g.op("Gather", padded, _mirror_index(g, _scalar(g, shape, 3), "r"), axis=3, out="padded")
    batch = g.slice(shape, 0, 1, 0)
    zero = helper.make_tensor("", FLOAT, [1], [0.0])
    inits = [
        g.op("ConstantOfShape", g.op("Concat", batch, g.ints(c), "hw", axis=0), value=zero)
        for c in (4, 4, 16, 16)
    ]
    taps = g.op("Mul", "k_win", "k_win")
    g.nodes.append(
        helper.make_node(
            "Loop",
            [taps, "", *inits],
            ["sum_a", "sum_b", "dsum_a", "dsum_b"],
            body=_tap_body(),
        )
    )
    return g.nodes
