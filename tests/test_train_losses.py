"""Losses for training (models/losses.py, models/msssim.py, models/transfer.py): the transfer
curve, auto-exposure, SSIM / MS-SSIM against their definitions, OIDN's L1 + MS-SSIM mix."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rtdenoise.models.families.affinity import Affinity
from rtdenoise.models.losses import (
    LOSSES,
    dark_edge_l1,
    dark_edge_mask,
    l1_ms_ssim_loss,
    relative_l1,
    relmse,
    sequence_loss,
    smape,
    training_loss,
)
from rtdenoise.models.msssim import MS_SSIM_WEIGHTS, ms_ssim, scales_for, ssim, window_for
from rtdenoise.models.registry import build_model
from rtdenoise.models.transfer import autoexposure, perceptual_transfer

TINY = {"widths": [8, 12], "kernel_size": 5, "refine_width": 8}


def test_transfer_curve_is_srgb_below_one_log_above_and_c1():
    x = torch.tensor([0.0, 0.002, 0.0031308, 0.01, 0.18, 0.5, 1.0], dtype=torch.float64)
    srgb = torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.pow(1 / 2.4) - 0.055)
    torch.testing.assert_close(perceptual_transfer(x), srgb)
    big = torch.tensor([2.0, 100.0, 65504.0], dtype=torch.float64)
    torch.testing.assert_close(perceptual_transfer(big), 1 + 1.055 / 2.4 * torch.log(big))
    # continuous at both joints; C1 at 1 (the standard's own toe joint has a 1.7 % slope step)
    for joint, step in ((0.0031308, 0.02), (1.0, 1e-3)):
        lo, hi = torch.tensor([joint - 1e-7, joint + 1e-7], dtype=torch.float64)
        assert abs(float(perceptual_transfer(hi) - perceptual_transfer(lo))) < 1e-5
        g = []
        for v in (joint - 1e-6, joint + 1e-6):
            t = torch.tensor(v, dtype=torch.float64, requires_grad=True)
            perceptual_transfer(t).backward()
            g.append(float(t.grad))
        assert abs(g[0] - g[1]) / g[1] < step, (joint, g)
    grid = torch.logspace(-6, 4.8, 500, dtype=torch.float64)
    y = perceptual_transfer(grid)
    assert bool((y[1:] > y[:-1]).all())
    torch.testing.assert_close(perceptual_transfer(-grid), -y)
    zero = torch.zeros((), requires_grad=True)
    perceptual_transfer(zero).backward()
    assert float(zero.grad) == pytest.approx(12.92)  # an output of 0 still gets a gradient


def test_autoexposure_is_key_over_geometric_mean_of_blocks():
    img = torch.full((1, 2, 3, 32, 32), 0.5)
    img[..., :16, :16] = 2.0  # 4 blocks of 16 x 16: luminance 2, 0.5, 0.5, 0.5
    gmean = float(np.exp(np.mean(np.log([2.0, 0.5, 0.5, 0.5]))))
    assert float(autoexposure(img)[0]) == pytest.approx(0.18 / gmean, rel=1e-5)
    # a 16-px block averages noise first: the geometric mean of pixels would differ
    noisy = torch.zeros(1, 3, 16, 16)
    noisy[..., ::2, ::2] = 4.0  # block mean 1.0
    assert float(autoexposure(noisy)[0]) == pytest.approx(0.18, rel=1e-5)
    # scale invariance, black clips, per-clip values, a crop smaller than a block
    x = torch.rand(3, 2, 3, 20, 24) + 0.01
    torch.testing.assert_close(autoexposure(7.0 * x), autoexposure(x) / 7.0)
    assert float(autoexposure(torch.zeros(1, 3, 8, 8))[0]) == 1.0
    assert autoexposure(torch.rand(2, 3, 5, 7)).shape == (2,)


def _window_ssim(x: np.ndarray, y: np.ndarray) -> float:
    """SSIM of two single-channel 11 x 11 images: one Gaussian window (Wang et al. 2004)."""
    r = np.arange(11) - 5.0
    g = np.exp(-(r**2) / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    mx, my = (w * x).sum(), (w * y).sum()
    vx, vy = (w * x * x).sum() - mx**2, (w * y * y).sum() - my**2
    cov = (w * x * y).sum() - mx * my
    c1, c2 = 0.01**2, 0.03**2
    return ((2 * mx * my + c1) * (2 * cov + c2)) / ((mx**2 + my**2 + c1) * (vx + vy + c2))


def test_ssim_matches_its_definition_and_ms_ssim_its_product():
    rng = np.random.default_rng(0)
    a, b = rng.random((2, 1, 1, 11, 11))
    got = float(ssim(torch.from_numpy(a), torch.from_numpy(b))[0])
    assert got == pytest.approx(_window_ssim(a[0, 0], b[0, 0]), abs=1e-10)
    # 32 px: 2 scales, weights 0.0448 and 0.2856 renormalised
    x = torch.rand(2, 3, 32, 32, dtype=torch.float64)
    y = (x + 0.2 * torch.randn_like(x)).clamp(0, 1)
    from rtdenoise.models.msssim import _gaussian, _ssim_cs

    k = _gaussian(11, 1.5, 3, x)
    _, cs1 = _ssim_cs(x, y, k, 1.0)
    s2, _ = _ssim_cs(
        torch.nn.functional.avg_pool2d(x, 2), torch.nn.functional.avg_pool2d(y, 2), k, 1.0
    )
    w = torch.tensor(MS_SSIM_WEIGHTS[:2], dtype=torch.float64)
    w = w / w.sum()
    torch.testing.assert_close(ms_ssim(x, y), cs1 ** w[0] * s2 ** w[1])
    torch.testing.assert_close(ms_ssim(x, x), torch.ones(2, dtype=torch.float64))
    assert float(ms_ssim(x, y).mean()) < float(ms_ssim(x, (x + 0.05 * (y - x))).mean()) < 1


def test_scales_and_windows_for_small_crops():
    assert [scales_for(s) for s in (16, 21, 22, 32, 64, 128, 176, 256)] == [1, 1, 2, 2, 3, 4, 5, 5]
    assert [window_for(s) for s in (3, 4, 9, 10, 11, 64)] == [3, 3, 9, 9, 11, 11]
    with pytest.raises(ValueError, match="at least 3"):
        ms_ssim(torch.rand(1, 3, 2, 8), torch.rand(1, 3, 2, 8))
    for side in (8, 16, 24):  # small crops: finite values and gradients
        x = torch.rand(2, 3, side, side, requires_grad=True)
        v = ms_ssim(x, torch.rand(2, 3, side, side)).mean()
        v.backward()
        assert torch.isfinite(v) and bool(torch.isfinite(x.grad).all())


def test_l1_ms_ssim_loss_definition_and_exposure_invariance():
    g = torch.Generator().manual_seed(1)
    ref = torch.rand(2, 3, 3, 24, 24, generator=g) * 4.0
    out = (ref * (1 + 0.3 * torch.randn(ref.shape, generator=g))).clamp_min(0)
    assert float(l1_ms_ssim_loss(ref, ref, 0.25)) == pytest.approx(0.0, abs=1e-6)
    # by hand: exposure from the reference, the curve, 0.16 L1 + 0.84 (1 - MS-SSIM)
    e = autoexposure(ref).view(-1, 1, 1, 1, 1)
    to, tr = perceptual_transfer(out * e), perceptual_transfer(ref * e)
    ms = ms_ssim(to.reshape(-1, 3, 24, 24), tr.reshape(-1, 3, 24, 24)).mean()
    expected = 0.16 * (to - tr).abs().mean() + 0.84 * (1 - ms)
    torch.testing.assert_close(l1_ms_ssim_loss(out, ref, 0.0), expected)
    d = ((to[:, 1:] - to[:, :-1]) - (tr[:, 1:] - tr[:, :-1])).abs().mean()
    torch.testing.assert_close(l1_ms_ssim_loss(out, ref, 0.5), expected + 0.5 * d)
    # a 50x brighter render of the same clip costs the same (exposure normalisation)
    torch.testing.assert_close(
        l1_ms_ssim_loss(50 * out, 50 * ref, 0.25), l1_ms_ssim_loss(out, ref, 0.25)
    )
    assert l1_ms_ssim_loss(out[:, 0], ref[:, 0]).shape == ()  # single frames (N, 3, H, W)


def test_training_loss_names():
    model = build_model("afn", TINY)
    assert training_loss("paper", model) == model.loss
    assert training_loss("smape", model) is sequence_loss
    assert training_loss("l1-ms-ssim", model) is l1_ms_ssim_loss
    assert set(LOSSES) == {"paper", "smape", "l1-ms-ssim"}
    with pytest.raises(ValueError, match="unknown loss"):
        training_loss("l2", model)
    # a family's regulariser (a public hook) is kept when the loss is replaced
    model.regulariser = lambda: torch.tensor(0.5)
    o, r = torch.rand(1, 2, 3, 16, 16), torch.rand(1, 2, 3, 16, 16)
    fn = training_loss("smape", model)
    torch.testing.assert_close(fn(o, r, 0.25), sequence_loss(o, r, 0.25) + 0.5)


def test_relmse_weight_adds_the_unsaturated_term():
    """--relmse-weight adds w x mean((o - t)^2 / (t^2 + 0.01)) to any loss; a light smeared onto a
    dark pixel costs far more there than in SMAPE, which saturates at 1."""
    model = build_model("afn", TINY)
    o, r = torch.rand(1, 2, 3, 16, 16), torch.rand(1, 2, 3, 16, 16)
    expected = ((o - r) ** 2 / (r**2 + 1e-2)).mean()
    torch.testing.assert_close(relmse(o, r), expected)
    fn = training_loss("smape", model, relmse_weight=0.5)
    torch.testing.assert_close(fn(o, r, 0.25), sequence_loss(o, r, 0.25) + 0.5 * expected)
    assert training_loss("smape", model, relmse_weight=0.0) is sequence_loss
    smeared = r.clone()
    smeared[..., 0, 0] = 20.0
    dark = r.clone()
    dark[..., 0, 0] = 0.02
    assert float(relmse(smeared, dark)) > 100 * float(smape(smeared, dark))
    with pytest.raises(ValueError, match="relmse_weight"):
        training_loss("smape", model, relmse_weight=-1.0)


def test_rel_l1_weight_adds_a_bounded_unsaturated_term():
    """--rel-l1-weight adds w x mean(|o - t| / (|t| + 0.1)); with relMSE in the same loss both
    are added. Its gradient at a smeared pixel stays 1 / (t + 0.1) however bright the smear (so
    it neither saturates like SMAPE nor grows with the error like relMSE)."""
    model = build_model("afn", TINY)
    o, r = torch.rand(1, 2, 3, 16, 16), torch.rand(1, 2, 3, 16, 16)
    expected = ((o - r).abs() / (r.abs() + 0.1)).mean()
    torch.testing.assert_close(relative_l1(o, r), expected)
    fn = training_loss("smape", model, rel_l1_weight=0.5)
    torch.testing.assert_close(fn(o, r, 0.25), sequence_loss(o, r, 0.25) + 0.5 * expected)
    both = training_loss("smape", model, relmse_weight=0.25, rel_l1_weight=0.5)
    torch.testing.assert_close(both(o, r, 0.25), fn(o, r, 0.25) + 0.25 * relmse(o, r))
    dark = torch.full((1, 1, 3, 4, 4), 0.02)
    for smear in (5.0, 50.0):
        out = dark.clone()
        out[..., 0, 0] = smear
        out.requires_grad_(True)
        relative_l1(out, dark).backward()
        per_pixel = float(out.grad[..., 0, 0].mean()) * out.numel()
        assert per_pixel == pytest.approx(1 / (0.02 + 0.1), rel=1e-5)
    with pytest.raises(ValueError, match="rel_l1_weight"):
        training_loss("smape", model, rel_l1_weight=-1.0)


def test_dark_edge_weight_weighs_only_the_dark_pixels_beside_a_bright_one():
    """--dark-edge-weight adds w x the relative L1 of the pixels whose reference is at most
    1/20 of the brightest within 2 px (that one >= 0.5): the 24 neighbours of a small light on a
    dark wall, not the light, not the wall further out, not a dim patch nor a mild edge."""
    ref = torch.full((1, 2, 3, 16, 16), 0.01)
    ref[..., 8, 8] = 10.0  # a small light
    ref[..., 1:4, 1:4] = 0.3  # dim: below 0.5
    ref[..., 11:, 11:] = 0.1  # a corner at 0.1 holding a bright patch: a 10:1 edge
    ref[..., 13:, 13:] = 1.0
    mask = dark_edge_mask(ref)
    assert mask.shape == (1, 2, 1, 16, 16)
    light = torch.zeros(16, 16)
    light[6:11, 6:11] = 1.0
    light[8, 8] = 0.0
    torch.testing.assert_close(mask[0, 0, 0], light)
    out = ref.clone()
    out[..., 8, 9] = 5.0  # smeared beside the light: counted
    out[..., 0, 15] = 5.0  # wrong on the wall far off: not counted
    out[..., 8, 8] = 1.0  # the light itself: not counted
    expected = 3 * 2 * (5.0 - 0.01) / (0.01 + 0.1) / ref.numel()
    assert float(dark_edge_l1(out, ref)) == pytest.approx(expected, rel=1e-5)
    model = build_model("afn", TINY)
    fn = training_loss("smape", model, dark_edge_weight=2.0)
    torch.testing.assert_close(
        fn(out, ref, 0.25), sequence_loss(out, ref, 0.25) + 2.0 * dark_edge_l1(out, ref)
    )
    with pytest.raises(ValueError, match="dark_edge_weight"):
        training_loss("smape", model, dark_edge_weight=-1.0)


def test_first_frame_weight_adds_the_first_frames_loss_once_more_times_w():
    """--first-frame-weight w adds w x the loss (relative terms in, temporal term out) of each
    clip's first frame: only frame 0's error moves it, and an affinity model's bandwidth
    regulariser is still counted once (the whole clip's loss takes it)."""
    model = build_model("afn", TINY)
    o, r = torch.rand(2, 4, 3, 16, 16) + 0.1, torch.rand(2, 4, 3, 16, 16) + 0.1
    plain = training_loss("smape", model, rel_l1_weight=0.5)
    fn = training_loss("smape", model, rel_l1_weight=0.5, first_frame_weight=3.0)
    expected = plain(o, r, 0.25) + 3.0 * plain(o[:, :1], r[:, :1], 0.0)
    torch.testing.assert_close(fn(o, r, 0.25), expected)
    later = o.clone()
    later[:, 1:] = r[:, 1:]  # later frames exact: the extra term is unchanged
    extra = fn(later, r, 0.25) - plain(later, r, 0.25)
    torch.testing.assert_close(extra, 3.0 * plain(o[:, :1], r[:, :1], 0.0))
    assert training_loss("smape", model, first_frame_weight=0.0) is sequence_loss
    with pytest.raises(ValueError, match="first_frame_weight"):
        training_loss("smape", model, first_frame_weight=-1.0)

    affinity = build_model("affinity", Affinity.example_config)
    affinity._bandwidths = [torch.tensor(2.0)]
    loss = training_loss("smape", affinity, first_frame_weight=1.0)(o, r, 0.0)
    first = sequence_loss(o[:, :1], r[:, :1], 0.0)
    torch.testing.assert_close(loss, sequence_loss(o, r, 0.0) + 1e-5 * 2.0 + first)
