"""The C input guard of librtdenoise_ops (native_ops/guard.cpp, rtdenoise_guard.h), which C
and C++ hosts call, is runtime/guard.py's `guard_buffer` bit for bit: the same float32 values
(signed zeros included), the same NaN/Inf pixel mask, clamped and outlier counts and "zero
everywhere", for every buffer name, on random buffers (hypothesis) with NaN, +-Inf, values
beyond the ranges, huge motion, fireflies alone and in pairs, zero guides and 1 x 1, 1 x N and
N x 1 frames; and its errors are return codes. Through ctypes (runtime/bridge/native_cpp.py);
skipped, with the reason, where the library was not built."""

from __future__ import annotations

import ctypes

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.runtime.guard import GUIDES, guard_buffer, guard_buffers
from rtdenoise.runtime.sequences.frames import find_frames, read_frame
from rtdenoise.shipped import sample_sequences

_REASON = native_cpp.unavailable_reason()
pytestmark = pytest.mark.skipif(
    _REASON is not None, reason=f"the C++ library rtdenoise_ops was not built: {_REASON}"
)

NAMES = ["color", "color_b", "albedo", "normal", "depth", "motion", "samples", "other"]
CHANNELS = {"depth": 1, "motion": 2, "samples": 1}
SPECIAL = [np.nan, -np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 1.0, 1.5, 1e-30, 1e-45, 16.0,
           1024.0, 1025.0, 1e4, 65504.0, 65505.0, 1e6, 1e10, 1.1e10, 1e30, 3e38, -3e38]  # fmt: skip
VALUES = st.one_of(st.sampled_from(SPECIAL), st.floats(width=32))


def bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


def assert_same(name: str, a: np.ndarray) -> None:
    """The C guard, in place and into another array, gives what the Python guard gives."""
    before = a.copy()
    py = guard_buffer(name, a)
    assert np.array_equal(bits(a), bits(before)), "the Python guard changed its input"
    for in_place in (True, False):
        c = native_cpp.guard_buffer(name, a, in_place=in_place)
        where = f"{name} {a.shape} in_place={in_place}"
        diff = np.flatnonzero(bits(c.array) != bits(py.array))
        if len(diff):
            i = diff[0]
            pytest.fail(
                f"{where}: {len(diff)} values differ, first at {np.unravel_index(i, a.shape)}: "
                f"input {a.flat[i]!r}, C {c.array.flat[i]!r}, Python {py.array.flat[i]!r}"
            )
        if py.nonfinite is None:
            assert c.nonfinite is None, where
        else:
            assert c.nonfinite is not None and np.array_equal(c.nonfinite, py.nonfinite), where
        assert (c.clamped, c.outliers, c.zero) == (py.clamped, py.outliers, py.zero), where
    assert native_cpp.zero_guide(name, py.array) == (py.zero and name in GUIDES)


def plausible(name: str, shape: tuple[int, ...], rng: np.random.Generator, scale: float):
    """A buffer of `name` with values a renderer writes."""
    if name in ("color", "color_b"):
        a = scale * rng.exponential(1.0, shape)
    elif name == "albedo":
        a = rng.random(shape)
    elif name == "normal":
        a = rng.uniform(-1, 1, shape)
    elif name == "depth":
        a = rng.uniform(0.1, 100, shape)
    elif name == "motion":
        a = rng.normal(0, 3, shape)
    else:
        a = scale * rng.normal(0, 1, shape)
    return a.astype(np.float32)


@st.composite
def buffers(draw, names: list[str] = NAMES) -> tuple[str, np.ndarray]:
    """A buffer name and a (C, H, W) or (1, C, H, W) float32 array: plausible values (seeded),
    then drawn values written over pixels, channels, rows or all of it, fireflies (alone or
    next to another one) and, for motion, displacements far beyond the frame."""
    name = draw(st.sampled_from(names))
    c = CHANNELS.get(name, draw(st.sampled_from([3, 1, 4])))
    kind = draw(st.sampled_from(["any", "1x1", "1xN", "Nx1"]))
    h = 1 if kind in ("1x1", "1xN") else draw(st.integers(1, 12))
    w = 1 if kind in ("1x1", "Nx1") else draw(st.integers(1, 12))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    scale = draw(st.sampled_from([1e-3, 1.0, 30.0, 1e3]))
    a = plausible(name, (c, h, w), rng, scale)
    if draw(st.booleans()):
        a[:] = np.float32(draw(st.sampled_from([0.0, -0.0])))  # a zero (missing) buffer
    for _ in range(draw(st.integers(0, 5))):
        value = np.float32(draw(VALUES))
        where = draw(st.sampled_from(["pixel", "value", "channel", "row", "all"]))
        y, x = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        if where == "pixel":
            a[:, y, x] = value
        elif where == "value":
            a[draw(st.integers(0, c - 1)), y, x] = value
        elif where == "channel":
            a[draw(st.integers(0, c - 1))] = value
        elif where == "row":
            a[:, y] = value
        else:
            a[:] = value
    for _ in range(draw(st.integers(0, 3))):  # fireflies, some of them in pairs
        y, x = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        peak = draw(st.floats(1000.0, 70000.0, width=32))
        a[draw(st.integers(0, c - 1)), y, x] = peak
        if draw(st.booleans()):
            yy, xx = min(h - 1, y + draw(st.integers(0, 1))), min(w - 1, x + 1)
            a[:, yy, xx] = np.float32(peak * draw(st.floats(0.0, 2.0, width=32)))
    if name == "motion" and draw(st.booleans()):
        a[draw(st.integers(0, 1)), draw(st.integers(0, h - 1))] = np.float32(
            draw(st.sampled_from([1.0, -1.0])) * draw(st.floats(1.0, 3e38))
        )
    if draw(st.booleans()):
        a = a[None]  # (1, C, H, W), as a graph input
    return name, a


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(buffers())
def test_c_guard_is_the_python_guard_bit_for_bit(case):
    name, a = case
    assert_same(name, a)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(buffers(["color", "color_b"]))
def test_c_guard_is_the_python_guard_on_colour(case):
    """The outlier rule has the most steps: more examples of the two buffers it applies to."""
    name, a = case
    assert_same(name, a)


def firefly_frame(h: int, w: int, peaks: list[tuple[int, int, float]], c: int = 3, base=0.5):
    a = np.full((c, h, w), base, np.float32)
    for y, x, v in peaks:
        a[:, y, x] = v
    return a


@pytest.mark.parametrize(
    "a",
    [
        firefly_frame(1, 1, [(0, 0, 1e5)]),  # alone in a 1 x 1 frame: above the range -> 0
        firefly_frame(1, 1, [(0, 0, 5e4)]),  # no neighbour: scaled by 0
        firefly_frame(1, 9, [(0, 0, 5e4)]),
        firefly_frame(1, 9, [(0, 4, 5e4), (0, 5, 3e4)]),  # two adjacent: both stay
        firefly_frame(9, 1, [(8, 0, 5e4)]),
        firefly_frame(9, 1, [(3, 0, 2000.0), (4, 0, 2000.0)]),
        firefly_frame(7, 8, [(0, 0, 4e4), (6, 7, 1e4), (3, 3, 1500.0)]),  # corners, centre
        firefly_frame(7, 8, [(3, 3, 1e4), (4, 4, 1e4)]),  # diagonal pair
        firefly_frame(7, 8, [(3, 3, 1e4), (3, 5, 1e4)]),  # two apart: both isolated
        firefly_frame(5, 5, [(2, 2, 1023.0)]),  # below 64 x 16: a normal Monte Carlo sample
        firefly_frame(5, 5, [(2, 2, 1025.0), (2, 3, 16.0)]),  # 1025 > 64 x 16
        firefly_frame(5, 5, [(2, 2, 2e4), (0, 0, -0.0)], c=1),
        firefly_frame(5, 5, [(2, 2, 2e4)], c=1, base=-0.0),  # scaled by a neighbour max of -0
        firefly_frame(4, 4, [(0, 0, 2e4), (3, 3, -0.0)], c=2, base=0.0),
    ],
)
def test_fireflies_alone_and_in_pairs(a):
    for name in ("color", "color_b"):
        assert_same(name, a)


def test_every_name_on_the_edge_cases():
    """NaN, +Inf, -Inf and values beyond both ends of every range, each alone in a buffer of
    every rule and in every size class; zero and negative-zero buffers."""
    for name in NAMES:
        c = CHANNELS.get(name, 3)
        for h, w in [(1, 1), (1, 7), (7, 1), (4, 5)]:
            for v in SPECIAL + [2 * max(h, w), 2 * max(h, w) + 1, -2 * max(h, w) - 1]:
                a = np.full((c, h, w), 0.25, np.float32)
                a[-1, h - 1, w // 2] = v
                assert_same(name, a)
                assert_same(name, np.full((c, h, w), v, np.float32))


def test_zero_guides_are_told_apart_from_other_buffers():
    for name in NAMES:
        for value in (0.0, -0.0):
            z = np.full((CHANNELS.get(name, 3), 4, 6), value, np.float32)
            assert native_cpp.zero_guide(name, z) == (name in GUIDES)
            assert_same(name, z)
        nan = np.full((3, 4, 6), np.nan, np.float32)  # NaN everywhere: zero once guarded
        assert not native_cpp.zero_guide(name, nan)
        assert native_cpp.guard_buffer(name, nan).zero == (name not in ("motion",))


def test_a_frame_mask_collects_every_buffer_like_the_guard_report():
    """One nonfinite_mask passed for every buffer of a frame holds the union that
    GuardReport.nonfinite_pixels counts."""
    rng = np.random.default_rng(3)
    frame = {n: plausible(n, (CHANNELS.get(n, 3), 9, 11), rng, 1.0) for n in NAMES[:6]}
    frame["color"][1, 2, 3] = np.nan
    frame["albedo"][0, 2, 3] = np.inf
    frame["motion"][1, 8, 0] = -np.inf
    frame["depth"][0, 0, 10] = np.nan
    _, report = guard_buffers(frame)
    lib = native_cpp.guard_library()
    mask = np.zeros((9, 11), np.uint8)
    for name, a in frame.items():
        out = np.empty_like(a)
        rc = lib.rtdenoise_guard_buffer(name.encode(), a.ctypes.data, out.ctypes.data,
                                        a.shape[0], 9, 11, None, mask.ctypes.data)  # fmt: skip
        assert rc == 0
    assert int(mask.sum()) == report.nonfinite_pixels == 3


def test_the_committed_frames_pass_alike():
    for path in find_frames(sample_sequences()[0])[:2]:
        for name, a in read_frame(path).buffers.items():
            assert_same(name, np.asarray(a, np.float32))


def test_bad_arguments_are_error_codes():
    lib = native_cpp.guard_library()
    a = np.ones((3, 4, 5), np.float32)
    out = np.empty_like(a)
    counts = native_cpp.GuardCounts()
    p, o = a.ctypes.data, out.ctypes.data

    def call(name=b"color", src=p, dst=o, planes=3, h=4, w=5):
        return lib.rtdenoise_guard_buffer(name, src, dst, planes, h, w, ctypes.byref(counts), None)

    assert call() == 0 and counts.zero == 0
    assert call(name=None) == call(src=None) == call(dst=None) == -1
    for shape in [(0, 4, 5), (3, 0, 5), (3, 4, 0), (-1, 4, 5), (3, 2**40, 2**40), (2**62, 2, 2)]:
        assert call(planes=shape[0], h=shape[1], w=shape[2]) == -2, shape
    assert call(dst=p + 4) == -3  # overlapping, not the same array
    assert call(dst=p) == 0  # in place
    assert lib.rtdenoise_guard_zero_guide(b"albedo", None, 3) == -1
    assert lib.rtdenoise_guard_zero_guide(None, p, 3) == -1
    assert lib.rtdenoise_guard_zero_guide(b"albedo", p, 0) == -2
    for code in (0, -1, -2, -3, -4, -5, 7):
        assert lib.rtdenoise_guard_error(code)
    with pytest.raises(ValueError, match="planes, height and width"):
        native_cpp.guard_buffer("color", np.ones((0, 4, 5), np.float32))
