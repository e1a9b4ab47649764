"""BilateralGrid (Meng20) in its three forms: torch reference == ONNX function body (ORT,
portable) == fast kernel (ORT with the numba kernels, and called directly) == an independent
numpy spelling of eqs. (8)-(13) that weighs every pixel against every cell; edge cases (empty
cells, guides at and beyond 0 and 255, sizes not divisible by s, C = 1 and 3); gradients of the
torch form w.r.t. image and guide (float64 gradcheck)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from op_forms import RTOL, all_forms, assert_forms_agree, rel_err

from rtdenoise.models.ops.bilateral_grid import bilateral_grid
from rtdenoise.ops.bilateral_grid import MENG20_GRIDS, grid_shape
from rtdenoise.runtime.kernels import KERNELS

OP = "BilateralGrid"


def tent64(u: np.ndarray) -> np.ndarray:
    return np.maximum(1.0 - np.sqrt(u * u + 1e-7), 0.0)


def bilateral_grid_numpy(image: np.ndarray, guide: np.ndarray, s: int, d: int) -> np.ndarray:
    """float64, dense: the weight of every pixel for every cell from the coordinates of eq. (12),
    splat = eqs. (10)-(11), slice = eq. (13) over cells with a positive weight sum."""
    n, c, h, w = image.shape
    gh, gw, _ = grid_shape(h, w, s, d)
    image = image.astype(np.float64)
    g = np.clip(guide[:, 0].astype(np.float64), 0.0, 255.0)
    wy = tent64((np.arange(h)[None] + 0.5) / s - (np.arange(gh)[:, None] + 0.5))  # (Gh, H)
    wx = tent64((np.arange(w)[None] + 0.5) / s - (np.arange(gw)[:, None] + 0.5))  # (Gw, W)
    z = (g + 0.5) * d / 256.0
    wz = tent64(z[:, None] - (np.arange(d)[None, :, None, None] + 0.5))  # (N, D, H, W)
    sums = np.einsum("iy,jx,nkyx,ncyx->ncijk", wy, wx, wz, image, optimize=True)
    total = np.einsum("iy,jx,nkyx->nijk", wy, wx, wz, optimize=True)
    filled = total > 0
    mean = np.where(filled[:, None], sums / np.where(filled, total, 1.0)[:, None], 0.0)
    num = np.einsum("iy,jx,nkyx,nijk,ncijk->ncyx", wy, wx, wz, filled, mean, optimize=True)
    den = np.einsum("iy,jx,nkyx,nijk->nyx", wy, wx, wz, filled, optimize=True)[:, None]
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def _inputs(rng, n, c, h, w, hdr=10.0):
    image = (hdr * rng.random((n, c, h, w))).astype(np.float32)
    guide = (255.0 * rng.random((n, 1, h, w))).astype(np.float32)
    return image, guide


CASES = [
    # (N, C, H, W, s, D)
    (1, 3, 16, 16, 4, 64),  # divisible
    (2, 3, 13, 17, 4, 64),  # not divisible by s: ceil(13/4) x ceil(17/4) cells
    (1, 1, 13, 17, 8, 32),  # C = 1
    (2, 3, 13, 17, 16, 16),  # one cell row, two columns
    (1, 3, 11, 9, 3, 10),  # odd s, D not dividing 256
    (1, 2, 6, 7, 1, 4),  # s = 1: a cell per pixel
    (1, 3, 9, 10, 2, 1),  # D = 1: a plain (guide-free) tent-weighted downsample/upsample
    (1, 7, 10, 9, 4, 16),  # C = 7: the fast kernel runs channels 3 at a time
]


@pytest.mark.parametrize("n,c,h,w,s,d", CASES)
def test_random_guides_all_forms_match_dense_numpy(n, c, h, w, s, d):
    image, guide = _inputs(np.random.default_rng(h * w + s), n, c, h, w)
    attrs = {"cell_size": s, "grid_depth": d}
    outs = all_forms(OP, [image, guide], attrs)
    assert_forms_agree(outs, bilateral_grid_numpy(image, guide, s, d))


@pytest.mark.parametrize("s,d", MENG20_GRIDS)
def test_guides_at_and_beyond_0_and_255(s, d):
    """Exactly 0 and 255 (the ends of GuideNet's range) and values beyond, which clamp to them."""
    rng = np.random.default_rng(s)
    image, _ = _inputs(rng, 1, 3, 21, 19)
    choice = rng.integers(0, 4, (1, 1, 21, 19))
    guide = np.choose(choice, [0.0, 255.0, -40.0, 300.0]).astype(np.float32)
    attrs = {"cell_size": s, "grid_depth": d}
    outs = all_forms(OP, [image, guide], attrs)
    expected = bilateral_grid_numpy(image, guide, s, d)
    assert_forms_agree(outs, expected)
    clamped = np.clip(guide, 0.0, 255.0)
    for form, out in all_forms(OP, [image, clamped], attrs).items():
        assert rel_err(out, expected) <= RTOL, form


def test_an_edge_in_the_guide_stops_the_filter():
    """Two plateaus of the guide, 0 and 255, over two image halves of values 1 and 5: the halves
    land in depth cells far apart, so the slice returns each half unblurred; with one guide
    value for both halves the grid blurs across the edge."""
    h, w = 16, 24
    image = np.ones((1, 3, h, w), np.float32)
    image[..., w // 2 :] = 5.0
    guide = np.zeros((1, 1, h, w), np.float32)
    guide[..., w // 2 :] = 255.0
    attrs = {"cell_size": 4, "grid_depth": 64}
    for form, out in all_forms(OP, [image, guide], attrs).items():
        np.testing.assert_allclose(out, image, rtol=1e-6, err_msg=form)
    flat = np.full_like(guide, 128.0)
    for form, out in all_forms(OP, [image, flat], attrs).items():
        assert 1.5 < out[0, 0, 0, w // 2 - 1] < 4.5, form  # blurred across the edge
        assert rel_err(out, bilateral_grid_numpy(image, flat, 4, 64)) <= RTOL, form


@pytest.mark.parametrize("value", [0.0, 2.5, -2.0])
def test_constant_image_is_kept_whatever_the_sign(value):
    """A weighted mean of a constant: every pixel, including those of the last partial cell
    row and column (ceil grid), gets the constant back. Non-empty is decided by the shared
    weight sum: the official per-channel test 'value > 0' would return 0 for 0 and -2."""
    rng = np.random.default_rng(3)
    image = np.full((2, 3, 13, 18), value, np.float32)
    guide = (255.0 * rng.random((2, 1, 13, 18))).astype(np.float32)
    for s, d in MENG20_GRIDS:
        for form, out in all_forms(OP, [image, guide], {"cell_size": s, "grid_depth": d}).items():
            np.testing.assert_allclose(out, value, atol=1e-5, err_msg=f"{form} s={s}")


def test_empty_cells_are_skipped_not_averaged_as_zero():
    """Guides in two narrow bands (0..10 and 245..255): most depth cells of every column stay
    empty. An average that counted empty cells as 0 (or did not renormalise) would darken the
    output; eq. (13) keeps a positive image positive and matches the dense reference."""
    rng = np.random.default_rng(4)
    image = (1.0 + rng.random((1, 3, 20, 20))).astype(np.float32)
    band = rng.integers(0, 2, (1, 1, 20, 20)) * 245.0
    guide = (band + 10.0 * rng.random((1, 1, 20, 20))).astype(np.float32)
    outs = all_forms(OP, [image, guide], {"cell_size": 4, "grid_depth": 64})
    assert_forms_agree(outs, bilateral_grid_numpy(image, guide, 4, 64))
    for form, out in outs.items():
        assert out.min() >= 1.0 - 1e-5 and out.max() <= 2.0 + 1e-5, form


def test_fast_kernel_on_a_larger_image_with_many_tasks():
    rng = np.random.default_rng(5)
    image, guide = _inputs(rng, 2, 3, 45, 70)
    ref = bilateral_grid(torch.from_numpy(image), torch.from_numpy(guide), 4, 64).numpy()
    assert rel_err(KERNELS[OP](image, guide, 4, 64), ref) <= RTOL
    assert rel_err(ref, bilateral_grid_numpy(image, guide, 4, 64)) <= RTOL


def test_non_finite_guides_do_not_crash_the_fast_kernel():
    """The runtime replaces NaN/Inf inputs before the graph; the kernel itself stays memory
    safe (integer-clamped cell indices) whatever reaches it."""
    rng = np.random.default_rng(6)
    image, guide = _inputs(rng, 1, 3, 12, 12)
    guide[0, 0, 3, 4] = np.nan
    guide[0, 0, 5, 6] = np.inf
    guide[0, 0, 7, 8] = -np.inf
    out = KERNELS[OP](image, guide, 4, 64)
    assert out.shape == image.shape


def test_validation_messages():
    image, guide = torch.rand(1, 3, 8, 8), torch.rand(1, 2, 8, 8)
    with pytest.raises(ValueError, match="guide has 2 channels"):
        bilateral_grid(image, guide, 4, 64)
    with pytest.raises(ValueError, match="cell_size >= 1"):
        KERNELS[OP](image.numpy(), guide[:, :1].numpy(), 0, 64)


# ------------------------------------------------------------------ gradients (torch form)


@pytest.fixture
def one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _guide_away_from_kinks(rng, shape, d: int) -> np.ndarray:
    """Guides whose depth coordinate is >= 0.02 cells from a corner switch (t integer), where
    the tent's derivative jumps and finite differences would straddle it."""
    g = 20.0 + 215.0 * rng.random(shape)
    t = (g + 0.5) * d / 256.0 - 0.5
    frac = t - np.floor(t)
    return np.where((frac < 0.02) | (frac > 0.98), g + 0.1 * 256.0 / d, g)


@pytest.mark.parametrize("s,d", [(2, 8), (3, 4)])
def test_gradcheck_image_and_guide(one_torch_thread, s, d):
    rng = np.random.default_rng(7 + s)
    image = torch.from_numpy(rng.random((1, 2, 5, 7)) * 3.0).requires_grad_(True)
    guide = torch.from_numpy(_guide_away_from_kinks(rng, (1, 1, 5, 7), d)).requires_grad_(True)

    def op(a, b):
        return bilateral_grid(a, b, s, d)

    assert torch.autograd.gradcheck(op, (image, guide), eps=1e-6, atol=1e-5)


def test_guide_gradient_is_nonzero_and_finite():
    """GuideNet learns through the guide: d(loss)/d(guide) exists and is finite everywhere,
    also where guides sit exactly at 0 and 255."""
    rng = np.random.default_rng(8)
    image = torch.from_numpy(rng.random((1, 3, 16, 16), dtype=np.float32))
    g = rng.random((1, 1, 16, 16), dtype=np.float32) * 255.0
    g[..., :2, :] = 0.0
    g[..., -2:, :] = 255.0
    guide = torch.from_numpy(g).requires_grad_(True)
    image.requires_grad_(True)
    out = bilateral_grid(image, guide, 4, 64)
    (out * torch.linspace(0, 1, 16)).sum().backward()
    assert torch.isfinite(guide.grad).all() and torch.isfinite(image.grad).all()
    assert float(guide.grad.abs().sum()) > 0 and float(image.grad.abs().sum()) > 0
