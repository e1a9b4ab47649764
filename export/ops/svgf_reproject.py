"""SvgfReproject as an ONNX function body; spec: rtdenoise.ops.svgf_reproject.

Body: the torch form's standard ops, step by step: forward differences (Slice, Sub, Abs, the
last row / column concatenated again) for the fwidths, the pixel grid plus motion, and per tap
a clamped flat index, one GatherElements of the (N, C + 4, H*W) planes, the in-image, depth
and normal tests and a Where. Both attributes are read as values: the fallback is computed
always and selected where `fallback` is 1, the eroded mask (a MaxPool of the negated,
1-padded mask) where `erode` is 1.
"""

from __future__ import annotations

import onnx

from ._graph import FLOAT, INT64, Graph
from .base import attr_const, function_body
from .cross_regression import _scalar


def _diff(g: Graph, x: str, axis: int) -> str:
    """|x[k + 1] - x[k]| along `axis`, the last difference repeated."""
    big = 1 << 62
    d = g.op(
        "Abs",
        g.op(
            "Sub",
            g.op("Slice", x, g.ints(1), g.ints(big), g.ints(axis)),
            g.op("Slice", x, g.ints(0), g.ints(-1), g.ints(axis)),
        ),
    )
    return g.op("Concat", d, g.op("Slice", d, g.ints(-1), g.ints(big), g.ints(axis)), axis=axis)


def _sum3(g: Graph, x: str) -> str:
    """Channel sum of an (N, 3, H, W) tensor as c0 + c1 + c2."""
    c0, c1, c2 = g.ops("Split", [x], 3, axis=1, num_outputs=3)
    return g.op("Add", g.op("Add", c0, c1), c2)


def _tap(g: Graph, fx: str, fy: str) -> tuple[str, str]:
    """(values (N, C, H, W), passes (N, 1, H, W) bool) of the taps at integer float positions."""
    ix = g.op("Clip", g.op("Cast", fx, to=INT64), "zero_i", "w1_i")
    iy = g.op("Clip", g.op("Cast", fy, to=INT64), "zero_i", "h1_i")
    idx = g.op("Reshape", g.op("Add", g.op("Mul", iy, "w_i"), ix), "idx_shape")
    picked = g.op("GatherElements", "flat", g.op("Expand", idx, "flat_dims"), axis=2)
    gathered = g.op("Reshape", picked, "cube_shape")
    value, gn, gz = g.ops("Split", [gathered, "split_sizes"], 3, axis=1)
    inside = g.op(
        "And",
        g.op(
            "And",
            g.op("GreaterOrEqual", fx, "f0"),
            g.op("LessOrEqual", fx, "w1_f"),
        ),
        g.op("And", g.op("GreaterOrEqual", fy, "f0"), g.op("LessOrEqual", fy, "h1_f")),
    )
    depth_ok = g.op("LessOrEqual", g.op("Abs", g.op("Sub", gz, "depth")), "depth_tol")
    d = g.op("Sub", gn, "normal")
    dn = g.op("Sqrt", _sum3(g, g.op("Mul", d, d)))
    ok = g.op("And", g.op("And", inside, depth_ok), g.op("LessOrEqual", dn, "normal_tol"))
    return value, ok


@function_body("SvgfReproject")
def svgf_reproject_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.SvgfReproject in standard ops (see the module docstring)."""
    g = Graph("svgf")
    f = lambda v: g.const(v, FLOAT)  # noqa: E731
    g.op("Identity", f(0.0), out="f0")
    g.op("Identity", g.const(0, INT64), out="zero_i")
    one_i = g.const(1, INT64)
    shape = g.op("Shape", "previous")
    c, h, w = (_scalar(g, shape, k) for k in (1, 2, 3))
    g.op("Identity", w, out="w_i")
    g.op("Sub", h, one_i, out="h1_i")
    g.op("Sub", w, one_i, out="w1_i")
    g.op("Cast", "h1_i", to=FLOAT, out="h1_f")
    g.op("Cast", "w1_i", to=FLOAT, out="w1_f")
    batch = g.slice(shape, 0, 1, 0)
    c4 = g.op("Add", g.op("Slice", shape, g.ints(1), g.ints(2), g.ints(0)), g.ints(4))
    hw = g.slice(shape, 2, 4, 0)
    g.op("Concat", batch, c4, g.ints(-1), axis=0, out="flat_shape")
    g.op("Reshape", g.op("Concat", "previous", "prev_geometry", axis=1), "flat_shape", out="flat")
    g.op("Shape", "flat", out="flat_dims")
    g.op("Concat", batch, g.ints(1, -1), axis=0, out="idx_shape")
    g.op("Concat", batch, c4, hw, axis=0, out="cube_shape")
    g.op("Concat", g.op("Unsqueeze", c, g.ints(0)), g.ints(3, 1), axis=0, out="split_sizes")

    # fwidths and the tolerances of the tests
    fw_z = g.op("Max", _diff(g, "depth", 3), _diff(g, "depth", 2))
    s = g.op("Add", _diff(g, "normal", 3), _diff(g, "normal", 2))
    fw_n = g.op("Sqrt", _sum3(g, g.op("Mul", s, s)))
    eps = f(1e-2)
    g.op("Mul", "depth_threshold", g.op("Add", fw_z, eps), out="depth_tol")
    g.op("Mul", "normal_threshold", g.op("Add", fw_n, eps), out="normal_tol")

    # previous positions (N, 1, H, W)
    one = f(1.0)
    xs = g.op("Range", "f0", g.op("Cast", w, to=FLOAT), one)  # (W,)
    ys = g.op("Unsqueeze", g.op("Range", "f0", g.op("Cast", h, to=FLOAT), one), g.ints(1))
    mx, my = g.ops("Split", ["motion"], 2, axis=1, num_outputs=2)
    px, py = g.op("Add", xs, mx), g.op("Add", ys, my)

    # bilinear taps, each tested, renormalised
    x0, y0 = g.op("Floor", px), g.op("Floor", py)
    ax, ay = g.op("Sub", px, x0), g.op("Sub", py, y0)
    ex, ey = g.op("Sub", one, ax), g.op("Sub", one, ay)
    x1, y1 = g.op("Add", x0, one), g.op("Add", y0, one)
    acc = total = None
    for fx, fy, wx, wy in ((x0, y0, ex, ey), (x1, y0, ax, ey), (x0, y1, ex, ay), (x1, y1, ax, ay)):
        value, ok = _tap(g, fx, fy)
        wgt = g.op("Where", ok, g.op("Mul", wx, wy), "f0")
        term = g.op("Mul", wgt, value)
        acc = term if acc is None else g.op("Add", acc, term)
        total = wgt if total is None else g.op("Add", total, wgt)
    valid = g.op("GreaterOrEqual", total, eps)
    safe = g.op("Where", valid, total, one)
    warped = g.op("Where", valid, g.op("Div", acc, safe), "f0")

    # 3 x 3 fallback around the rounded position, where the attribute asks for it
    half = f(0.5)
    rx, ry = g.op("Floor", g.op("Add", px, half)), g.op("Floor", g.op("Add", py, half))
    fsum = count = None
    for oy in (-1, 0, 1):
        for ox in (-1, 0, 1):
            value, ok = _tap(g, g.op("Add", rx, f(float(ox))), g.op("Add", ry, f(float(oy))))
            picked = g.op("Where", ok, value, "f0")
            hit = g.op("Cast", ok, to=FLOAT)
            fsum = picked if fsum is None else g.op("Add", fsum, picked)
            count = hit if count is None else g.op("Add", count, hit)
    g.node(attr_const("fallback_i", "fallback"))
    use = g.op(
        "And",
        g.op("And", g.op("Not", valid), g.op("Greater", count, "f0")),
        g.op("Equal", "fallback_i", one_i),
    )
    warped = g.op("Where", use, g.op("Div", fsum, g.op("Max", count, one)), warped)
    mask = g.op("Cast", g.op("Or", valid, use), to=FLOAT)

    # 3 x 3 erosion, out-of-image neighbours ignored (padded with 1)
    g.node(attr_const("erode_i", "erode"))
    padded = g.op("Pad", mask, g.ints(0, 0, 1, 1, 0, 0, 1, 1), one)
    eroded = g.op("Neg", g.op("MaxPool", g.op("Neg", padded), kernel_shape=[3, 3]))
    g.op("Where", g.op("Equal", "erode_i", one_i), eroded, mask, out="valid")
    g.op("Mul", warped, "valid", out="warped")
    return g.nodes
