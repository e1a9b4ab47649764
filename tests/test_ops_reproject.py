"""Reproject's `nearest` mode (affinity's history warp): every form reads, to the bit, the
pixel that numpy's rounding of the clamped source position picks, whatever the motion (far
off-screen, exactly half a pixel, NaN-free large values); and the bilinear mode still blurs.
The generic three-form and optional-attribute tests (test_ops_three_forms.py) run both modes
on the spec's examples."""

from __future__ import annotations

import numpy as np
import pytest
from op_forms import all_forms

from rtdenoise.ops import get_spec

OP = "Reproject"


def _nearest_numpy(previous: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """An independent spelling: round half up of the clamped position, then index."""
    n, c, h, w = previous.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    px = np.clip(xs + motion[:, 0], 0, w - 1)
    py = np.clip(ys + motion[:, 1], 0, h - 1)
    ix = np.floor(px + np.float32(0.5)).astype(np.int64)
    iy = np.floor(py + np.float32(0.5)).astype(np.int64)
    batch = np.arange(n)[:, None, None]
    return np.stack([previous[batch, ch, iy, ix] for ch in range(c)], axis=1)


def _motion(rng: np.random.Generator, n: int, h: int, w: int) -> np.ndarray:
    """Motion with fractions, exact halves, integers and far off-screen vectors."""
    motion = rng.uniform(-4.0, 4.0, (n, 2, h, w)).astype(np.float32)
    pick = rng.random((n, 2, h, w))
    motion[pick < 0.2] = np.round(motion[pick < 0.2]) + 0.5  # exact halves
    motion[(pick >= 0.2) & (pick < 0.3)] = np.round(motion[(pick >= 0.2) & (pick < 0.3)])
    motion[pick > 0.95] *= 1e3  # far outside: the border pixel
    return motion


@pytest.mark.parametrize("shape", [(1, 5, 9, 13), (2, 3, 16, 7), (1, 34, 32, 48)])
def test_nearest_reads_the_rounded_clamped_pixel_in_every_form(shape: tuple) -> None:
    rng = np.random.default_rng(sum(shape))
    n, c, h, w = shape
    previous = rng.standard_normal(shape).astype(np.float32)
    motion = _motion(rng, n, h, w)
    want = _nearest_numpy(previous, motion)
    outs = all_forms(OP, [previous, motion], {"nearest": 1})
    assert {"torch", "portable", "ort_fast", "numba"} <= set(outs)
    for form, got in outs.items():
        np.testing.assert_array_equal(got, want, err_msg=form)
    # a copy: every output value is one of the input's values of its channel
    assert np.isin(want[:, 0], previous[:, 0]).all()


def test_nearest_and_bilinear_differ_only_off_the_pixel_grid() -> None:
    """Integer motion: both modes read the same pixel; half-pixel motion: bilinear averages,
    nearest copies."""
    rng = np.random.default_rng(3)
    previous = rng.random((1, 2, 8, 10), dtype=np.float32)
    whole = np.full((1, 2, 8, 10), 1.0, np.float32)
    near = all_forms(OP, [previous, whole], {"nearest": 1})
    bil = all_forms(OP, [previous, whole], {"nearest": 0})
    for form in near:
        np.testing.assert_allclose(near[form], bil[form], rtol=0, atol=1e-7, err_msg=form)
    half = np.full((1, 2, 8, 10), 0.5, np.float32)
    near = all_forms(OP, [previous, half], {"nearest": 1})["ort_fast"]
    bil = all_forms(OP, [previous, half], {"nearest": 0})["ort_fast"]
    np.testing.assert_array_equal(near[0, :, :6, :8], previous[0, :, 1:7, 1:9])
    assert np.abs(bil - near).max() > 0.05


def test_nearest_must_be_0_or_1() -> None:
    spec = get_spec(OP)
    with pytest.raises(ValueError, match="nearest is 2"):
        spec.validate_call([(1, 3, 4, 4), (1, 2, 4, 4)], {"nearest": 2})
