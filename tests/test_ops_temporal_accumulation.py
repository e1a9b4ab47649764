"""TemporalAccumulation: every form gives all four outputs of the torch form (models.temporal),
the fast kernel to the bit, with every reprojection (per_tap 0 to 3); per_tap=1, 2 and 3 in
every form match an independent numpy spelling of SVGF's per-tap test (Schied17 s.4.1; 2 with
a tap brighter than 4x the darkest + 1 weighed down by its excess, 3 by its square) on a
disocclusion edge, all taps rejected, taps off-screen and reset; per_tap=2 keeps a bright line
out of its dark neighbours, 3 further, and both equal per_tap=1 where no tap is an outlier; a
node without per_tap (a model exported before it) runs the bilinear scheme on every path."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch
from op_forms import native_cpp_holds, rel_err, session

from rtdenoise.models.ops import TORCH_OPS
from rtdenoise.ops import get_spec
from rtdenoise.runtime.kernels import KERNELS

OP = "TemporalAccumulation"
BRIDGES = ("", "native", "extensions")  # "": the portable function body


def _inputs(shape: tuple[int, int, int, int], seed: int, reset: float = 0.0) -> list[np.ndarray]:
    inputs = get_spec(OP).example_inputs(shape, {}, np.random.default_rng(seed))
    inputs[6] = np.array(reset, np.float32)
    return inputs


@pytest.mark.parametrize("shape", [(1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 32, 48)])
@pytest.mark.parametrize("reset", [0.0, 1.0])
@pytest.mark.parametrize("per_tap", [0, 1, 2, 3])
def test_every_form_gives_every_output(shape, reset, per_tap) -> None:
    inputs = _inputs(shape, sum(shape), reset)
    with torch.no_grad():
        tensors = map(torch.from_numpy, inputs)
        ref = [t.numpy() for t in TORCH_OPS[OP].reference(*tensors, per_tap=per_tap)]
    blend = ref[1]
    assert 0.0 < (blend < 1.0).mean() < 1.0 or reset  # some pixels keep their history
    assert reset == 0.0 or (blend == 1.0).all()
    feed = dict(zip(get_spec(OP).input_names, inputs, strict=True))
    forms = {
        "numba": KERNELS[OP](*inputs, per_tap=per_tap),
        **{
            b or "portable": session(OP, (("per_tap", per_tap),), b).run(None, feed)
            for b in ("", "native", "extensions")
        },
    }
    for form, outs in forms.items():
        assert len(outs) == 4, form
        for got, want in zip(outs, ref, strict=True):
            assert got.shape == want.shape and got.dtype == np.float32, form
            if form == "portable":  # ORT's own Reproject / ReduceSum arithmetic
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-5, err_msg=form)
            else:
                np.testing.assert_array_equal(got, want, err_msg=form)


@pytest.mark.parametrize("per_tap", [0, 1, 2, 3])
def test_nonfinite_history_is_dropped_where_invalid(per_tap) -> None:
    """An invalid history is selected away, never multiplied by 0: a NaN history leaves the
    pixels that reject it finite (where it is valid it is used, as in the torch form; the
    runtime keeps NaN out of the state, tests/test_guard*.py)."""
    inputs = _inputs((1, 3, 16, 16), 5)
    inputs[4][:, :3] = np.nan  # every accumulated value of the history
    inputs[4][:, 3] = np.maximum(inputs[4][:, 3], 1.0)  # so blend 1 means: rejected
    outs = KERNELS[OP](*inputs, per_tap=per_tap)
    fresh = outs[1][:, 0] == 1.0  # the history was rejected
    assert 0 < fresh.mean() < 1
    assert np.isfinite(outs[0].transpose(1, 0, 2, 3)[:, fresh]).all()
    assert np.isnan(outs[0].transpose(1, 0, 2, 3)[:, ~fresh]).all()
    with torch.no_grad():
        ref = TORCH_OPS[OP].reference(*map(torch.from_numpy, inputs), per_tap=per_tap)
    for got, want in zip(outs, ref, strict=True):
        np.testing.assert_array_equal(got, want.numpy())


# ------------------------------------------------- per_tap = 1 against an independent spelling


def svgf_per_tap_numpy(
    inputs: list[np.ndarray], hdr: int = 0
) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """SVGF's reprojection (Schied17 s.4.1) with TemporalAccumulation's tests, written from the
    description, pixel by pixel in float64: the four pixels around the previous position
    p = (x + mx, y + my) are the bilinear taps; a tap counts if it lies in the previous frame,
    its depth is within depth_tolerance |depth| of the current pixel's and its normal's dot
    with the current normal exceeds normal_threshold; the history (colour and length) is the
    bilinear average over the counted taps, their weights renormalised, and is dropped where
    the counted taps weigh under 0.01 (no tap counts, in particular) or reset is 1. Then
    alpha = max(1 / (n + 1), min_alpha). hdr 1 (per_tap 2): the average weighs each counted
    tap by weight / (1 + its brightness above 4 x the darkest counted tap's + 1), brightness
    the mean of its C history colours (at least 0); hdr 2 (per_tap 3): by weight / (1 + that)
    squared; the 0.01 cut keeps the plain weights.
    Returns the four outputs, the number of counted taps per pixel among those of nonzero
    weight (N, H, W) and where the history was kept."""
    current, motion, depth, normal, ta, geo = (x.astype(np.float64) for x in inputs[:6])
    reset, tol, thr, min_alpha, max_history = (float(x) for x in inputs[6:])
    n_img, c, h, w = current.shape
    acc = np.zeros_like(current)
    blend = np.zeros((n_img, 1, h, w))
    next_ta = np.zeros((n_img, c + 1, h, w))
    counted = np.zeros((n_img, h, w), np.int64)
    kept = np.zeros((n_img, h, w), bool)
    for n in range(n_img):
        for y in range(h):
            for x in range(w):
                px, py = x + motion[n, 0, y, x], y + motion[n, 1, y, x]
                x0, y0 = int(np.floor(px)), int(np.floor(py))
                fx, fy = px - x0, py - y0
                d, nrm = depth[n, 0, y, x], normal[n, :, y, x]
                counted_taps = []
                for tx, ty, weight in (
                    (x0, y0, (1 - fx) * (1 - fy)),
                    (x0 + 1, y0, fx * (1 - fy)),
                    (x0, y0 + 1, (1 - fx) * fy),
                    (x0 + 1, y0 + 1, fx * fy),
                ):
                    if not (0 <= tx < w and 0 <= ty < h):
                        continue
                    if not abs(geo[n, 3, ty, tx] - d) < tol * abs(d):
                        continue
                    if not np.dot(geo[n, :3, ty, tx], nrm) > thr:
                        continue
                    counted[n, y, x] += weight > 0
                    counted_taps.append((weight, ta[n, :, ty, tx]))
                total = sum(weight for weight, _ in counted_taps)
                bright = [max(value[:c].mean(), 0.0) for _, value in counted_taps]
                bound = 4.0 * min(bright, default=0.0) + 1.0
                weighed, history = 0.0, np.zeros(c + 1)
                for (weight, value), b in zip(counted_taps, bright, strict=True):
                    weight /= (1.0 + max(b - bound, 0.0)) ** hdr
                    weighed += weight
                    history += weight * value
                kept[n, y, x] = reset == 0.0 and total >= 0.01
                if kept[n, y, x]:
                    history /= weighed
                else:
                    history[:] = 0.0
                alpha = max(1.0 / (history[c] + 1.0), min_alpha)
                acc[n, :, y, x] = alpha * current[n, :, y, x] + (1 - alpha) * history[:c]
                blend[n, 0, y, x] = alpha
                next_ta[n, :c, y, x] = acc[n, :, y, x]
                next_ta[n, c, y, x] = min(history[c] + 1.0, max_history)
    next_geometry = np.concatenate([normal, depth], axis=1)
    return [acc, blend, next_ta, next_geometry], counted, kept


def _every_form(inputs: list[np.ndarray], per_tap: int) -> dict[str, list[np.ndarray]]:
    """{form: the four outputs}: torch, portable ORT, ORT with numba (native and extensions
    bridges), numba called directly and, where built, the C++ library."""
    feed = dict(zip(get_spec(OP).input_names, inputs, strict=True))
    attrs = (("per_tap", per_tap),)
    with torch.no_grad():
        ref = TORCH_OPS[OP].reference(*map(torch.from_numpy, inputs), per_tap=per_tap)
    forms = {
        "torch": [t.numpy() for t in ref],
        "numba": list(KERNELS[OP](*inputs, per_tap=per_tap)),
    }
    bridges = ["", "native", "extensions"] + (["native-cpp"] if native_cpp_holds(OP) else [])
    for b in bridges:
        forms[b or "portable"] = session(OP, attrs, b).run(None, feed)
    return forms


def _frame(h: int = 16, w: int = 16, c: int = 3, motion=(0.5, 0.5)) -> list[np.ndarray]:
    """A flat frame facing the camera (normal +z, depth 2) whose previous frame equals it,
    a constant motion, history colour (x + w y) / (h w) (a value per pixel, in [0, 1)) per
    channel, history length 8."""
    f32 = np.float32
    ys, xs = np.mgrid[0:h, 0:w].astype(f32)
    normal = np.zeros((1, 3, h, w), f32)
    normal[:, 2] = 1.0
    depth = np.full((1, 1, h, w), 2.0, f32)
    history = np.broadcast_to((xs + w * ys) / (h * w), (1, c, h, w))
    ta_state = np.concatenate([history, np.full((1, 1, h, w), 8.0, f32)], axis=1)
    mv = np.stack([np.full((h, w), motion[0], f32), np.full((h, w), motion[1], f32)])[None]
    current = np.random.default_rng(0).random((1, c, h, w), dtype=f32)
    scalars = [0.0, 0.1, 0.9, 0.2, 64.0]  # reset, depth / normal tests, min_alpha, max_history
    return [
        current,
        mv.astype(f32),
        depth,
        normal,
        ta_state.astype(f32),
        np.concatenate([normal, depth], axis=1),
        *(np.array(s, f32) for s in scalars),
    ]


def _disocclusion() -> list[np.ndarray]:
    """A foreground square (depth 2) over a background (depth 6) in both frames, motion half a
    pixel on both axes: along the square's edges 2 of the 4 taps (weights 1/4 each) see the
    other surface, at its corners 1 or 3."""
    inputs = _frame()
    depth = np.full((1, 1, 16, 16), 6.0, np.float32)
    depth[:, :, 4:11, 4:11] = 2.0
    inputs[2] = depth
    inputs[5] = np.concatenate([inputs[3], depth], axis=1)
    return inputs


def _all_rejected() -> list[np.ndarray]:
    """The previous frame saw another surface everywhere (depth 4 vs 2): no tap passes."""
    inputs = _disocclusion()
    inputs[5] = inputs[5].copy()
    inputs[5][:, 3] = 2.0 * inputs[2][:, 0]
    return inputs


def _off_screen() -> list[np.ndarray]:
    """Motion left and up by 0.25 to 2.5 px, varying per pixel, plus random geometry noise:
    border pixels have taps outside the previous frame, some all of them."""
    inputs = _frame()
    rng = np.random.default_rng(7)
    inputs[1] = -rng.uniform(0.25, 2.5, (1, 2, 16, 16)).astype(np.float32)
    inputs[4][:, 3] = rng.integers(1, 80, (1, 16, 16))
    return inputs


def _reset() -> list[np.ndarray]:
    inputs = _disocclusion()
    inputs[6] = np.array(1.0, np.float32)
    return inputs


def _random() -> list[np.ndarray]:
    """The spec's example inputs (a quarter of the previous pixels on another surface, motion
    within 2 px, a tenth far off-screen) at 16 x 16."""
    return get_spec(OP).example_inputs((2, 3, 16, 16), {}, np.random.default_rng(3))


PER_TAP_CASES = {
    "disocclusion": _disocclusion,
    "all_rejected": _all_rejected,
    "off_screen": _off_screen,
    "reset": _reset,
    "random": _random,
}


@pytest.mark.parametrize("case", sorted(PER_TAP_CASES))
@pytest.mark.parametrize("per_tap", [1, 2, 3])
def test_per_tap_every_form_matches_an_independent_svgf_spelling(case, per_tap) -> None:
    inputs = PER_TAP_CASES[case]()
    expected, counted, kept = svgf_per_tap_numpy(inputs, hdr=per_tap - 1)
    forms = _every_form(inputs, per_tap=per_tap)
    assert "portable" in forms and "native" in forms and "numba" in forms
    for form, outs in forms.items():
        assert len(outs) == 4, form
        for o, (got, want) in enumerate(zip(outs, expected, strict=True)):
            assert got.shape == want.shape and got.dtype == np.float32, (form, o)
            # float32 vs float64: within 1e-5 of max(1, the output's largest value)
            assert rel_err(got, want) <= 1e-5, (form, o, rel_err(got, want))
    blend = expected[1][:, 0]
    if case in ("all_rejected", "reset"):  # history dropped: length 0, alpha 1, current
        assert (blend == 1.0).all() and (expected[2][:, -1] == 1.0).all()
        np.testing.assert_array_equal(forms["torch"][0], inputs[0])
    if case == "off_screen":
        assert 0 < kept.mean() < 1  # some pixels keep part of their history, some none
        assert (kept <= (counted > 0)).all() and (counted[kept] < 4).any()
        assert (blend[~kept] == 1.0).all() and (blend[kept] < 1.0).all()


def test_per_tap_differs_from_bilinear_where_some_taps_fail() -> None:
    """At the square's edge and corners (1 to 3 of 4 taps on the other surface) per_tap keeps
    the foreground taps only, renormalised; the bilinear scheme tests the interpolated depth
    (a mix of 2 and 6) and keeps or drops the whole interpolated history: the results differ
    there and agree where all 4 taps pass."""
    inputs = _disocclusion()
    _, counted, _ = svgf_per_tap_numpy(inputs)
    assert {1, 2, 3} <= set(np.unique(counted).tolist())  # corners and edges
    per_tap = _every_form(inputs, per_tap=1)
    bilinear = _every_form(inputs, per_tap=0)
    partial = (counted[0] > 0) & (counted[0] < 4)
    # the last row and column: their off-screen taps are rejected, but there the bilinear
    # scheme's clamped position reads the same pixels (within half a pixel of the border)
    partial[-1, :] = partial[:, -1] = False
    assert partial.sum() >= 20
    for form in per_tap:
        a, b = per_tap[form][2][0], bilinear[form][2][0]  # next_ta (C + 1, H, W)
        differs = np.abs(a - b).max(axis=0) > 1e-3
        assert differs[partial].all(), form
        np.testing.assert_array_equal(a[:, counted[0] == 4], b[:, counted[0] == 4], err_msg=form)


def _bright_line(motion: float) -> list[np.ndarray]:
    """The flat frame of `_frame` (32 x 32) with a history of 0.02 everywhere except 50 on
    column 12 (a small light on a dark wall, demodulated) and a constant horizontal motion."""
    inputs = _frame(32, 32, motion=(motion, 0.0))
    inputs[4] = inputs[4].copy()
    inputs[4][:, :3] = 0.02
    inputs[4][:, :3, :, 12] = 50.0
    return inputs


@pytest.mark.parametrize("motion", [0.25, 0.5, -0.3])
def test_per_tap_hdr_keeps_a_bright_line_out_of_its_dark_neighbours(motion) -> None:
    """A sub-pixel warp of a one-pixel line: per_tap=1 moves a share of the line's 50 into the
    pixel beside it (its bilinear weight: 12.5 to 25); per_tap=2 weighs the bright tap down by
    its excess over 4 x 0.02 + 1 (1 / 49.9) and keeps it under 1.1 there, per_tap=3 by the
    square (1 / 2492) under 0.1, as every form does; far from the line all three agree to the
    bit."""
    inputs = _bright_line(motion)
    plain, hdr = _every_form(inputs, per_tap=1), _every_form(inputs, per_tap=2)
    hdr2 = _every_form(inputs, per_tap=3)
    neighbour = 11 if motion > 0 else 13  # the pixel whose taps reach the line
    for form in plain:
        history = (1 - 0.2) * 1.0  # (1 - alpha) at history length 8: alpha = max(1/9, 0.2)
        bled = plain[form][0][0, 0, :, neighbour] - 0.2 * inputs[0][0, 0, :, neighbour]
        np.testing.assert_allclose(bled / history, 50 * abs(motion) + 0.02 * (1 - abs(motion)),
                                   rtol=1e-5, err_msg=form)  # fmt: skip
        kept = hdr[form][0][0, 0, :, neighbour] - 0.2 * inputs[0][0, 0, :, neighbour]
        assert (kept / history < 1.1).all() and (kept / history > 0.02).all(), form
        kept2 = hdr2[form][0][0, 0, :, neighbour] - 0.2 * inputs[0][0, 0, :, neighbour]
        assert (kept2 / history < 0.1).all() and (kept2 / history > 0.02).all(), form
        far = np.r_[0:9, 16:31]  # columns whose taps all read 0.02
        for weighted in (hdr, hdr2):
            for got, want in zip(weighted[form], plain[form], strict=True):
                np.testing.assert_array_equal(got[..., far], want[..., far], err_msg=form)


@pytest.mark.parametrize("per_tap", [2, 3])
@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_per_tap_hdr_is_the_plain_average_where_no_tap_is_an_outlier(scale, per_tap) -> None:
    """A checkerboard history (0.1 and 1, times 1 to 1.2 per pixel; lengths 1 to 80, taps
    off-screen): no tap brighter than 4 x the darkest + 1 (at most 1.2 against 1.4), so
    per_tap=2 (and 3) weighs nothing down and gives per_tap=1's outputs to the bit; three times
    as bright (3.6 against 2.2) the bright squares are outliers and it differs."""
    inputs = _off_screen()
    ys, xs = np.mgrid[0:16, 0:16]
    checker = np.where((xs + ys) % 2 == 1, 1.0, 0.1) * (1.0 + 0.2 * inputs[4][0, 0])
    inputs[4] = inputs[4].copy()
    inputs[4][:, :3] = (scale * checker).astype(np.float32)
    plain, hdr = _every_form(inputs, per_tap=1), _every_form(inputs, per_tap=per_tap)
    for form in plain:
        same = all(np.array_equal(a, b) for a, b in zip(hdr[form], plain[form], strict=True))
        assert same == (scale == 1.0), form
        dropped = hdr[form][1] == 1.0  # the cut: the same pixels keep their history
        np.testing.assert_array_equal(dropped, plain[form][1] == 1.0, err_msg=form)
        assert 0 < dropped.mean() < 1, form


def test_per_tap_must_be_0_to_3() -> None:
    """(A node without per_tap runs bilinear on every path: test_op_specs.py's
    test_a_node_without_its_optional_attributes_runs_as_before.)"""
    with pytest.raises(ValueError, match="per_tap is 4; expected 0, 1, 2 or 3"):
        KERNELS[OP](*_disocclusion(), per_tap=4)


def test_shipped_demo_runs_on_the_extensions_bridge_with_per_tap_written_out() -> None:
    """demo:wskp-small was exported before per_tap: its TemporalAccumulation node gets per_tap=0
    written out for onnxruntime-extensions, every other byte of the model kept."""
    from rtdenoise.runtime.session import resolve_model
    from rtdenoise.runtime.static_check import fill_optional_attributes

    data = resolve_model("demo:wskp-small").read_bytes()
    old = onnx.load_from_string(data)
    nodes = [n for n in old.graph.node if n.op_type == OP]
    assert nodes and all(not n.attribute for n in nodes)
    new = onnx.load_from_string(fill_optional_attributes(data))
    for a, b in zip(old.graph.node, new.graph.node, strict=True):
        if a.op_type == OP:
            assert [(x.name, x.i) for x in b.attribute] == [("per_tap", 0)]
            del b.attribute[:]
        assert a == b
    assert old.functions == new.functions and old.graph.initializer == new.graph.initializer
    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.sequences.synthetic import synthetic_frames

    den = Denoiser("demo:wskp-small", fast_kernels="extensions")
    assert den.bridge == "extensions"
    frames = synthetic_frames(den.required_buffers, 2, 16, 16)
    assert all(np.isfinite(den.process(f)).all() for f in frames)
