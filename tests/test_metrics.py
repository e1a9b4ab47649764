"""Metrics against hand-computed values on tiny images."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtdenoise.runtime.sequences import metrics as m

T1 = 0.5 ** (1 / 2.4)  # tau(1) = (1 / 2)^(1/2.4), Isik21 eq. 15


def img(*rows_per_channel) -> np.ndarray:
    return np.array(rows_per_channel, dtype=np.float32)


def test_tonemap():
    x = np.array([[[1.0, 0.0, -2.0, 3.0]]])
    np.testing.assert_allclose(m.tonemap(x), [[[T1, 0.0, 0.0, 0.75 ** (1 / 2.4)]]], rtol=1e-12)


def test_psnr_by_hand():
    ones, zeros = np.ones((3, 2, 2)), np.zeros((3, 2, 2))
    # mse = tau(1)^2 -> psnr = -10 log10(0.5^(2/2.4)) = (10 / 1.2) log10(2) = 2.5086 dB
    assert m.psnr(ones, zeros) == pytest.approx(10 / 1.2 * math.log10(2), rel=1e-12)
    assert m.psnr(ones, zeros) == pytest.approx(2.50858, abs=1e-5)
    one_px = np.zeros((3, 2, 2))
    one_px[:, 0, 1] = 1.0  # one pixel of four differs: mse / 4 -> +10 log10(4) dB
    assert m.psnr(one_px, zeros) == pytest.approx(2.50858 + 6.02060, abs=1e-4)
    assert m.psnr(one_px, one_px) == math.inf


def test_smape_by_hand():
    a = img([[1.0, 2.0], [0.0, 0.0]])
    b = img([[3.0, 2.0], [0.0, -1.0]])
    expected = (2 / 4.001 + 0 + 0 + 1 / 1.001) / 4
    assert m.smape(a, b) == pytest.approx(expected, rel=1e-6)
    # per channel (Lee24 eq. 5), not the L1-over-colour form of Isik21 eq. 11 (which gives 2/6.003)
    a = img([[1.0]], [[0.0]], [[0.0]])
    b = img([[0.0]], [[0.0]], [[1.0]])
    assert m.smape(a, b) == pytest.approx(2 / (3 * 1.001), rel=1e-6)
    assert m.smape(b, b) == 0.0


def test_relmse_by_hand():
    a = img([[2.0, 0.0]], [[1.0, 1.0]], [[0.0, 0.0]])
    b = img([[1.0, 0.0]], [[1.0, 0.0]], [[-2.0, 0.0]])
    # (1/1.01 + 0/0.01 + 0 + 1/0.01 + 4/4.01 + 0) / 6
    expected = (1 / 1.01 + 1 / 0.01 + 4 / 4.01) / 6
    assert m.relmse(a, b) == pytest.approx(expected, rel=1e-6)
    assert m.relmse(b, b) == 0.0


def test_trmae_by_hand():
    ests = [np.full((3, 2, 2), v, np.float32) for v in (0.0, 1.0, 1.0)]
    refs = [np.full((3, 2, 2), v, np.float32) for v in (0.0, 2.0, 2.0)]
    # t=1: |1 - 2| summed over 3 channels / (3 * 2 + 0.01), divided by 3 -> 1 / 6.01; t=2: 0
    assert m.trmae(ests, refs) == pytest.approx((1 / 6.01 + 0) / 2, rel=1e-6)
    assert m.trmae(refs, refs) == 0.0
    assert math.isnan(m.trmae(ests[:1], refs[:1]))


def _ssim_brute_force(x: np.ndarray, y: np.ndarray) -> float:
    """One 11x11 window per channel, 2-D Gaussian weights written out (Wang et al. 2004)."""
    g = np.exp(-(np.arange(-5, 6) ** 2) / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    vals = []
    for xc, yc in zip(m.tonemap(x), m.tonemap(y), strict=True):
        mx, my = (w * xc).sum(), (w * yc).sum()
        vx, vy = (w * xc * xc).sum() - mx**2, (w * yc * yc).sum() - my**2
        cxy = (w * xc * yc).sum() - mx * my
        c1, c2 = 0.01**2, 0.03**2
        vals.append((2 * mx * my + c1) * (2 * cxy + c2) / ((mx**2 + my**2 + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_ssim_by_hand():
    ones, zeros = np.ones((3, 11, 11)), np.zeros((3, 11, 11))
    # constant images: variances 0 -> SSIM = C1 / (tau(1)^2 + C1)
    assert m.ssim(ones, zeros) == pytest.approx(1e-4 / (T1**2 + 1e-4), rel=1e-9)
    rng = np.random.default_rng(0)
    x = rng.random((3, 11, 11)) * 2
    y = x + rng.normal(0, 0.3, x.shape)
    assert m.ssim(x, y) == pytest.approx(_ssim_brute_force(x, y), rel=1e-9)
    assert 0.2 < m.ssim(x, y) < 0.95
    assert m.ssim(x, x) == pytest.approx(1.0, abs=1e-12)
    # larger image: mean over the valid windows (separable filter == 2-D weights per window)
    # 20 x 3 windows: several 8-row strips, the last one partial
    x = rng.random((3, 30, 13))
    y = x * 0.5 + rng.random(x.shape) * 0.2
    windows = [
        _ssim_brute_force(x[:, i : i + 11, j : j + 11], y[:, i : i + 11, j : j + 11])
        for i in range(20)
        for j in range(3)
    ]
    assert m.ssim(x, y) == pytest.approx(np.mean(windows), rel=1e-9)
    # smaller than the window: the largest odd window that fits (5 here)
    small = np.ones((3, 5, 7))
    assert m.ssim(small, 0 * small) == pytest.approx(1e-4 / (T1**2 + 1e-4), rel=1e-9)
    assert m.ssim(x[:, :5, :7], x[:, :5, :7]) == pytest.approx(1.0, abs=1e-12)


def test_identical_images():
    x = np.random.default_rng(1).random((3, 16, 16)).astype(np.float32) * 5
    got = m.frame_metrics(x, x)
    assert got == {"psnr": math.inf, "ssim": pytest.approx(1.0), "smape": 0.0, "relmse": 0.0}


def test_sequence_metrics_pooling_and_chain():
    zeros = np.zeros((3, 11, 11))
    seq = m.SequenceMetrics()
    seq.add(np.ones((3, 11, 11)), zeros)  # mse tau(1)^2
    seq.add(2 * np.ones((3, 11, 11)), 2 * np.ones((3, 11, 11)))  # mse 0
    s = seq.summary()
    # Isik21 eq. 14: the error is pooled over frames before the log
    assert s["psnr"] == pytest.approx(-10 * math.log10(T1**2 / 2), rel=1e-12)
    assert s["smape"] == pytest.approx((1 / 1.001 + 0) / 2, rel=1e-9)
    assert s["relmse"] == pytest.approx((1 / 0.01 + 0) / 2, rel=1e-9)
    # d est = 1, d ref = 2 per channel: 1 / 6.01 (as in test_trmae_by_hand)
    assert s["trmae"] == pytest.approx(1 / 6.01, rel=1e-6)
    assert [f["psnr"] for f in seq.frames][1] == math.inf
    broken = m.SequenceMetrics()
    broken.add(zeros, zeros)
    broken.add(zeros, zeros, consecutive=False)
    assert math.isnan(broken.summary()["trmae"])
    assert m.SequenceMetrics().summary() == {}
    with pytest.raises(ValueError, match="one shape"):
        m.psnr(zeros, zeros[:, :5])
