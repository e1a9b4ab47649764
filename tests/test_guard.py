"""The input guard (runtime/guard.py): each buffer's rule, pixel counts, outliers, copies."""

from __future__ import annotations

import numpy as np
import pytest

from rtdenoise.runtime.guard import (
    DEPTH_MAX,
    HALF_MAX,
    OUTLIER_FLOOR,
    OUTLIER_RATIO,
    GuardReport,
    GuardTotals,
    guard_buffer,
    guard_buffers,
    replace_nonfinite,
)
from rtdenoise.runtime.sequences.frames import find_frames, read_frame
from rtdenoise.shipped import sample_sequences


def ones(c: int, h: int = 6, w: int = 8) -> np.ndarray:
    return np.ones((c, h, w), np.float32)


def test_clean_buffers_pass_untouched_without_a_copy():
    for name, a in {"color": ones(3), "albedo": 0.5 * ones(3), "normal": -ones(3)}.items():
        g = guard_buffer(name, a)
        assert g.array is a and g.nonfinite is None and g.clamped == g.outliers == 0


@pytest.mark.parametrize(
    ("name", "value", "expected", "counted"),
    [
        ("color", np.nan, 0.0, "nonfinite"),
        ("color", np.inf, 0.0, "nonfinite"),
        ("color", -np.inf, 0.0, "nonfinite"),
        ("color", -5.0, 0.0, "clamped"),
        ("color", 1e5, 0.0, "clamped"),  # above the half range: Inf in half floats -> 0
        ("color", 3e38, 0.0, "clamped"),
        ("albedo", 7.0, 1.0, "clamped"),
        ("albedo", np.nan, 0.0, "nonfinite"),
        ("normal", 1e5, 1.0, "clamped"),
        ("normal", -1e5, -1.0, "clamped"),
        ("normal", np.inf, 0.0, "nonfinite"),
        ("depth", np.inf, DEPTH_MAX, "nonfinite"),  # the far plane
        ("depth", -np.inf, 0.0, "nonfinite"),
        ("depth", -3.0, 0.0, "clamped"),
        ("samples", 1e9, HALF_MAX, "clamped"),
        ("samples", np.nan, 0.0, "nonfinite"),
    ],
)
def test_rules(name, value, expected, counted):
    a = ones(1 if name == "depth" else 3)
    a[:, 2, 3] = value  # every channel of one pixel
    a[0, 4, 5] = value  # one channel of another
    given = a.copy()
    g = guard_buffer(name, a)
    np.testing.assert_array_equal(a, given)  # the caller's array: untouched
    assert g.array[0, 2, 3] == np.float32(expected) and g.array[0, 4, 5] == np.float32(expected)
    assert np.isfinite(g.array).all()
    got = {"nonfinite": int(g.nonfinite.sum()) if g.nonfinite is not None else 0,
           "clamped": g.clamped}  # fmt: skip
    assert got[counted] == 2 and sum(got.values()) == 2  # pixels, not values


def test_motion_is_bounded_by_the_frame_size_and_nan_is_off_screen():
    m = np.zeros((2, 5, 9), np.float32)
    m[0, 0, 0], m[1, 1, 1], m[0, 2, 2], m[1, 3, 3] = 1e30, -np.inf, np.nan, 17.0
    g = guard_buffer("motion", m)
    bound = 2 * 9
    assert g.array[0, 0, 0] == bound and g.array[1, 1, 1] == -bound
    assert g.array[0, 2, 2] == bound  # NaN -> off-screen: the history there is rejected
    assert g.array[1, 3, 3] == 17.0  # within the bound: as given
    assert g.clamped == 1 and int(g.nonfinite.sum()) == 2


def test_isolated_outliers_take_their_neighbour_maximum():
    c = ones(3, 9, 9)
    c[:, 4, 4] = [6e4, 3e4, 0.0]  # a firefly: scaled so its largest channel = neighbours' max
    c[:, 2, 6] *= 3.0  # neighbour max of the firefly stays 1 (not adjacent)
    c[:, 0, 0] = 900.0  # below 64 x 16: never an outlier whatever its neighbours
    c[1, 8, 8] = 1e4  # a corner firefly (3 neighbours)
    g = guard_buffer("color", c)
    np.testing.assert_allclose(g.array[:, 4, 4], [1.0, 0.5, 0.0])  # hue kept
    assert g.array[1, 8, 8] == pytest.approx(1.0) and g.array[0, 0, 0] == 900.0
    assert g.outliers == 2 and g.clamped == 0
    # bright surroundings raise the threshold: 64 x 100 = 6400 > 5000
    bright = 100 * ones(3, 5, 5)
    bright[:, 2, 2] = 5000.0
    assert guard_buffer("color", bright).outliers == 0
    # two adjacent outliers shield each other (documented): only range-checked
    pair = ones(3, 5, 5)
    pair[:, 2, 2] = pair[:, 2, 3] = 3e4
    assert guard_buffer("color", pair).outliers == 0
    assert OUTLIER_RATIO * OUTLIER_FLOOR == 1024.0


def test_callers_array_is_never_modified_owned_ones_are_fixed_in_place():
    a = ones(3)
    a[0, 0, 0] = np.nan
    g = guard_buffer("color", a)
    assert np.isnan(a[0, 0, 0]) and g.array[0, 0, 0] == 0.0
    b = a.copy()
    assert guard_buffer("color", b, owned=True).array is b and b[0, 0, 0] == 0.0


def test_frame_report_counts_pixels_and_flags_missing_guides():
    color, albedo, normal = ones(3), np.zeros((3, 6, 8), np.float32), ones(3)
    color[:, 1, 1] = np.nan  # 1 pixel, 3 values
    normal[0, 1, 1] = np.inf  # the same pixel in another buffer
    normal[0, 2, 2] = 1.5
    fixed, report = guard_buffers({"color": color, "albedo": albedo, "normal": normal})
    assert report.nonfinite == {"color": 1, "normal": 1} and report.nonfinite_pixels == 1
    assert report.clamped == {"normal": 1} and report.unusable == ("albedo",)
    assert report.changed and "albedo zero everywhere" in report.summary()
    totals = GuardTotals()
    totals.add(report)
    totals.add(GuardReport(reset="size change: 4x4 -> 8x8"))
    assert (totals.nonfinite_pixels, totals.clamped, totals.unusable_frames) == (1, 1, 1)
    assert totals.resets == {"size change": 1}
    assert not GuardReport().changed and GuardReport().summary() == ""


def test_replace_nonfinite_uses_the_buffer_rule():
    d = np.array([[[np.inf, np.nan, 2.0]]], np.float32)
    mask = replace_nonfinite("depth", d)
    assert d.tolist() == [[[DEPTH_MAX, 0.0, 2.0]]] and mask.tolist() == [[True, True, False]]
    assert replace_nonfinite("color", ones(3)) is None


def test_the_committed_sequences_pass_unchanged():
    """The guard changes nothing on real renders: the demo metrics stay what they were."""
    for seq in sample_sequences():
        for path in find_frames(seq):
            buffers = {k: v[None] for k, v in read_frame(path).buffers.items()}
            fixed, report = guard_buffers(buffers)
            assert not report.changed, (path, report)
            assert all(fixed[k] is buffers[k] for k in buffers)
