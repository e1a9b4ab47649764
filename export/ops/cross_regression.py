"""CrossRegression as an ONNX function body (Choi24 eqs. (4)-(7)); defined in
rtdenoise.ops.cross_regression.

Body, in float64 like the other forms (both regressions as one batch of 2N):
- per-pixel stack q = [y, albedo, normal, sigma, var, target] (14 channels); var from 9 Slices
  of the zero-padded image and of a ones plane (in-image 3x3 neighbours);
- mirrored padding by Gather with reflected indices (Range, Abs, Mod, Where);
- a Loop over the window^2 offsets accumulates X^T W X (2N, 3, 6, 6, Hc, Wc) and X^T W y
  (2N, 3, 6, Hc, Wc), each offset's window pixels being one strided Slice of the padded stack;
- the 6 x 6 Cholesky factorisation and the two triangular solves, unrolled into elementwise ops;
- a Loop over the covering centre offsets (dj, di) reconstructs every pixel (eq. (5)) from the
  coefficient grid gathered at rows p // stride + dj and columns p // stride + di.
"""

from __future__ import annotations

import onnx
from onnx import TensorProto, helper

from ._graph import DOUBLE, FLOAT, INT64, Graph
from .base import attr_const, function_body

P = 6
CHANNELS = 14  # y (3), albedo (3), normal (3), sigma, var, target (3)


def _variables(g: Graph, q: str, c: str) -> tuple[str, str]:
    """x(q; c) (B, 3, 6, ...) and w(c, q) (B, 1, ...) of stacks q, c (B, 14, ...)."""
    d = g.op("Sub", q, c)
    dy = g.slice(d, 0, 3, 1)
    scale = g.op("Add", g.op("Add", g.slice(c, 9, 10, 1), g.slice(q, 9, 10, 1)), g.const(1e-2))
    spread = g.op("Add", g.op("Add", g.slice(c, 10, 11, 1), g.slice(q, 10, 11, 1)), g.const(1e-4))
    dist = g.op("ReduceSum", g.op("Mul", dy, dy), g.ints(1), keepdims=1)
    w = g.op("Add", g.op("Exp", g.op("Neg", g.op("Div", dist, spread))), g.const(1e-7))
    x1 = g.op("Div", dy, scale)
    shape = g.op("Shape", x1)
    ones = g.op("Expand", g.const(1.0), shape)
    dn = [g.op("Expand", g.slice(d, 6 + k, 7 + k, 1), shape) for k in range(3)]
    parts = [ones, x1, g.slice(d, 3, 6, 1), *dn]
    x = g.op("Concat", *(g.unsqueeze(p, 2) for p in parts), axis=2)
    return x, w


def _scalar(g: Graph, shape: str, axis: int) -> str:
    """Dimension `axis` of a shape tensor as an int64 scalar."""
    return g.op("Gather", shape, g.const(axis, INT64), axis=0)


def _mirror_index(g: Graph, n: str, r: str) -> str:
    """Positions -r .. n - 1 + r reflected into [0, n) (period 2 (n - 1))."""
    one, two = g.const(1, INT64), g.const(2, INT64)
    idx = g.op("Range", g.op("Neg", r), g.op("Add", n, r), one)
    period = g.op("Mul", two, g.op("Sub", n, one))
    a = g.op("Mod", g.op("Abs", idx), period)
    return g.op("Where", g.op("GreaterOrEqual", a, n), g.op("Sub", period, a), a)


def _variance(g: Graph, y: str, ones: str, h: str, w: str) -> str:
    """||y - mean of the in-image 3x3 neighbours||^2 (B, 1, H, W)."""
    pads = g.ints(0, 0, 1, 1, 0, 0, 1, 1)
    yp, op = g.op("Pad", y, pads), g.op("Pad", ones, pads)
    total = count = None
    for i in range(3):
        for j in range(3):
            starts = g.ints(i, j)
            ends = g.op("Add", g.op("Concat", h, w, axis=0), starts)
            axes = g.ints(2, 3)
            ty = g.op("Slice", yp, starts, ends, axes)
            to = g.op("Slice", op, starts, ends, axes)
            total = ty if total is None else g.op("Add", total, ty)
            count = to if count is None else g.op("Add", count, to)
    mean = g.op("Div", g.op("Sub", total, y), g.op("Sub", count, g.const(1.0)))
    diff = g.op("Sub", y, mean)
    return g.op("ReduceSum", g.op("Mul", diff, diff), g.ints(1), keepdims=1)


def _normal_equations_body() -> onnx.GraphProto:
    """Offset t = (dy, dx): A += X^T W X, b += X^T W target over the centres' window pixels."""
    g = Graph("ne")
    dy = g.op("Div", "t", "k_win")
    dx = g.op("Mod", "t", "k_win")
    starts = g.op("Concat", g.unsqueeze(dy, 0), g.unsqueeze(dx, 0), axis=0)
    ends = g.op("Add", starts, "span")
    win = g.op("Slice", "padded", starts, ends, g.ints(2, 3), "steps")  # (B, 14, Hc, Wc)
    x, w = _variables(g, win, "centres")
    xw = g.op("Mul", x, g.unsqueeze(w, 2))  # (B, 3, 6, Hc, Wc)
    g.op("Add", "a_in", g.op("Mul", g.unsqueeze(xw, 3), g.unsqueeze(x, 2)), out="a_out")
    target = g.unsqueeze(g.slice(win, 11, 14, 1), 2)
    g.op("Add", "b_in", g.op("Mul", xw, target), out="b_out")
    g.op("Identity", "cond_in", out="cond_out")
    return helper.make_graph(
        g.nodes,
        "cross_regression_offset",
        [
            helper.make_tensor_value_info("t", INT64, []),
            helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
            helper.make_tensor_value_info("a_in", DOUBLE, None),
            helper.make_tensor_value_info("b_in", DOUBLE, None),
        ],
        [
            helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
            helper.make_tensor_value_info("a_out", DOUBLE, None),
            helper.make_tensor_value_info("b_out", DOUBLE, None),
        ],
    )


def _valid_index(g: Graph, n: str, nc: str, offset: str) -> tuple[str, str]:
    """Centre index p // stride + offset along an axis of n pixels, clipped to [0, nc), and
    whether that centre exists and its window covers p."""
    zero = g.const(0, INT64)
    pos = g.op("Range", zero, n, g.const(1, INT64))
    j = g.op("Add", g.op("Div", pos, "stride_"), offset)
    dist = g.op("Abs", g.op("Sub", pos, g.op("Mul", j, "stride_")))
    ok = g.op("And", g.op("LessOrEqual", dist, "r"), g.op("GreaterOrEqual", j, zero))
    ok = g.op("And", ok, g.op("Less", j, nc))
    clipped = g.op("Clip", j, zero, g.op("Sub", nc, g.const(1, INT64)))
    return clipped, ok


def _reconstruction_body() -> onnx.GraphProto:
    """Centre offset t = (dj, di): num += w x^T beta, den += w over the covered pixels."""
    g = Graph("rc")
    dj = g.op("Sub", g.op("Div", "t", "n_off"), "lo")
    di = g.op("Sub", g.op("Mod", "t", "n_off"), "lo")
    rows, vy = _valid_index(g, "h", "hc", dj)
    cols, vx = _valid_index(g, "w", "wc", di)
    grid = g.op("Gather", g.op("Gather", "grid", rows, axis=2), cols, axis=3)  # (B, 32, H, W)
    x, w = _variables(g, "q", g.slice(grid, 3 * P, 3 * P + CHANNELS, 1))
    coef = g.op("Reshape", g.slice(grid, 0, 3 * P, 1), "coef_shape")  # (B, 3, 6, H, W)
    pred = g.op("ReduceSum", g.op("Mul", x, coef), g.ints(2), keepdims=0)
    valid = g.op("And", g.unsqueeze(vy, 1), g.unsqueeze(vx, 0))
    w = g.op("Mul", w, g.op("Cast", valid, to=DOUBLE))
    g.op("Add", "num_in", g.op("Mul", w, pred), out="num_out")
    g.op("Add", "den_in", w, out="den_out")
    g.op("Identity", "cond_in", out="cond_out")
    return helper.make_graph(
        g.nodes,
        "cross_regression_centre",
        [
            helper.make_tensor_value_info("t", INT64, []),
            helper.make_tensor_value_info("cond_in", TensorProto.BOOL, []),
            helper.make_tensor_value_info("num_in", DOUBLE, None),
            helper.make_tensor_value_info("den_in", DOUBLE, None),
        ],
        [
            helper.make_tensor_value_info("cond_out", TensorProto.BOOL, []),
            helper.make_tensor_value_info("num_out", DOUBLE, None),
            helper.make_tensor_value_info("den_out", DOUBLE, None),
        ],
    )


def _cholesky_solve(g: Graph, a: str, b: str) -> str:
    """Solve (B, 3, 6, 6, Hc, Wc) SPD systems for (B, 3, 6, Hc, Wc) right-hand sides,
    unrolled: A = L L^T, L z = b, L^T beta = z. Returns beta (B, 3, 6, Hc, Wc)."""
    rows = g.ops("Split", [a], P, axis=2, num_outputs=P)
    m = [g.ops("Split", [row], P, axis=3, num_outputs=P) for row in rows]
    rhs = [
        g.op("Squeeze", part, g.ints(2)) for part in g.ops("Split", [b], P, axis=2, num_outputs=P)
    ]
    low: dict[tuple[int, int], str] = {}
    for i in range(P):
        for j in range(i + 1):
            s = g.op("Squeeze", m[i][j], g.ints(2, 3))
            for k in range(j):
                s = g.op("Sub", s, g.op("Mul", low[i, k], low[j, k]))
            low[i, j] = g.op("Sqrt", s) if i == j else g.op("Div", s, low[j, j])
    z: list[str] = []
    for i in range(P):
        s = rhs[i]
        for k in range(i):
            s = g.op("Sub", s, g.op("Mul", low[i, k], z[k]))
        z.append(g.op("Div", s, low[i, i]))
    beta: list[str] = [""] * P
    for i in reversed(range(P)):
        s = z[i]
        for k in range(i + 1, P):
            s = g.op("Sub", s, g.op("Mul", low[k, i], beta[k]))
        beta[i] = g.op("Div", s, low[i, i])
    return g.op("Concat", *(g.unsqueeze(bi, 2) for bi in beta), axis=2)


@function_body("CrossRegression")
def cross_regression_body(opset: int) -> list[onnx.NodeProto]:
    """rtdenoise.CrossRegression in standard ops (see the module docstring)."""
    g = Graph("cr")
    g.node(attr_const("k_win", "window"))
    g.node(attr_const("stride_", "stride"))
    one, two = g.const(1, INT64), g.const(2, INT64)
    g.op("Div", "k_win", two, out="r")
    cast = {n: g.op("Cast", n, to=DOUBLE) for n in ("y_a", "y_b", "albedo", "normal")}
    y = g.op("Concat", cast["y_a"], cast["y_b"], axis=0)
    target = g.op("Concat", cast["y_b"], cast["y_a"], axis=0)
    albedo = g.op("Concat", cast["albedo"], cast["albedo"], axis=0)
    normal = g.op("Concat", cast["normal"], cast["normal"], axis=0)

    shape = g.op("Shape", y)
    g.op("Identity", _scalar(g, shape, 2), out="h")
    g.op("Identity", _scalar(g, shape, 3), out="w")
    h1, w1 = g.unsqueeze("h", 0), g.unsqueeze("w", 0)
    ones = g.op(
        "Expand", g.const(1.0), g.op("Concat", g.slice(shape, 0, 1, 0), g.ints(1), h1, w1, axis=0)
    )
    var = _variance(g, y, ones, h1, w1)
    q = g.op("Concat", y, albedo, normal, g.op("Sqrt", var), var, target, axis=1, out="q")

    # Centres and the mirrored stack.
    stride_minus1 = g.op("Sub", "stride_", one)
    g.op("Div", g.op("Add", "h", stride_minus1), "stride_", out="hc")
    g.op("Div", g.op("Add", "w", stride_minus1), "stride_", out="wc")
    steps = g.op(
        "Concat", g.unsqueeze("stride_", 0), g.unsqueeze("stride_", 0), axis=0, out="steps"
    )
    g.op(
        "Slice", q, g.ints(0, 0), g.op("Concat", h1, w1, axis=0), g.ints(2, 3), steps, out="centres"
    )
    padded = g.op("Gather", q, _mirror_index(g, "h", "r"), axis=2)
    g.op("Gather", padded, _mirror_index(g, "w", "r"), axis=3, out="padded")
    # window pixels of offset (dy, dx): rows dy .. dy + stride (Hc - 1), every stride-th
    hc1, wc1 = g.unsqueeze("hc", 0), g.unsqueeze("wc", 0)
    extent = g.op("Concat", g.op("Sub", hc1, one), g.op("Sub", wc1, one), axis=0)
    g.op("Add", g.op("Mul", extent, steps), g.ints(1, 1), out="span")

    # Normal equations (eq. (4)) over the window^2 offsets.
    batch = g.slice(shape, 0, 1, 0)
    a_shape = g.op("Concat", batch, g.ints(3, P, P), hc1, wc1, axis=0)
    b_shape = g.op("Concat", batch, g.ints(3, P), hc1, wc1, axis=0)
    zero = helper.make_tensor("", DOUBLE, [1], [0.0])
    a0 = g.op("ConstantOfShape", a_shape, value=zero)
    b0 = g.op("ConstantOfShape", b_shape, value=zero)
    taps = g.op("Mul", "k_win", "k_win")
    a_sum, b_sum = g.ops("Loop", [taps, "", a0, b0], 2, body=_normal_equations_body())
    eye = helper.make_tensor(
        "", DOUBLE, [1, 1, P, P, 1, 1], [1e-3 * (i == j) for i in range(P) for j in range(P)]
    )
    a_sum = g.op("Add", a_sum, g.op("Constant", value=eye))
    beta = _cholesky_solve(g, a_sum, b_sum)  # (B, 3, 6, Hc, Wc)

    # Reconstruction (eq. (5)).
    coef = g.op("Reshape", beta, g.op("Concat", batch, g.ints(3 * P), hc1, wc1, axis=0))
    g.op("Concat", coef, "centres", axis=1, out="grid")
    g.op("Concat", batch, g.ints(3, P), h1, w1, axis=0, out="coef_shape")
    g.op("Div", "r", "stride_", out="lo")
    hi = g.op("Div", g.op("Add", "r", stride_minus1), "stride_")
    g.op("Add", g.op("Add", "lo", hi), one, out="n_off")
    num0 = g.op("ConstantOfShape", g.op("Concat", batch, g.ints(3), h1, w1, axis=0), value=zero)
    den0 = g.op("ConstantOfShape", g.op("Concat", batch, g.ints(1), h1, w1, axis=0), value=zero)
    centres = g.op("Mul", "n_off", "n_off")
    num, den = g.ops("Loop", [centres, "", num0, den0], 2, body=_reconstruction_body())
    pilots = g.op("Cast", g.op("Max", g.op("Div", num, den), g.const(0.0)), to=FLOAT)
    g.nodes.append(
        helper.make_node("Split", [pilots], ["pilot_a", "pilot_b"], axis=0, num_outputs=2)
    )
    return g.nodes
