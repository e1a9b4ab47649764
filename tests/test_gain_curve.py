"""crossreg's online gain curve (models/gain_curve.py): what it learns from the noisy radiance,
how it reads back, and that it is learned state (frozen frames keep it, a reset keeps it unless
the learning restarts)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from rtdenoise.models.families.crossreg import CrossRegConfig
from rtdenoise.models.gain_curve import GainCurve
from rtdenoise.models.registry import build_model


def _halves(dark: float, bright: float, size: int = 32) -> torch.Tensor:
    """(1, 3, size, size): the left half `dark`, the right half `bright`."""
    img = torch.full((1, 3, size, size), dark)
    img[..., size // 2 :] = bright
    return img


def test_each_brightness_learns_its_own_gain():
    """A dark region whose label is twice its output and a light whose label equals it: the
    curve doubles the dark pixels and leaves the light (a single gain would do neither)."""
    curve = GainCurve(bins=32, range=4.0, blur=1, prior=1.0, limit=4.0)
    out = _halves(0.05, 5.0)
    label = _halves(0.10, 5.0)
    stats = curve.statistics(out, label)
    assert stats.shape == (1, 64)
    corrected = curve.apply(out, stats)[0]
    interior = slice(2, 14), slice(18, 30)  # away from the edge the blur mixes
    dark, light = corrected[:, :, interior[0]], corrected[:, :, interior[1]]
    assert torch.allclose(dark, torch.full_like(dark, 0.10), rtol=0.02)
    assert torch.allclose(light, torch.full_like(light, 5.0), rtol=0.02)
    one_gain = float((label * out).sum() / (out * out).sum())  # what one gain would be
    assert abs(one_gain - 1.0) < 0.01  # the light's pixels decide it: the dark stays dark


def test_an_empty_curve_is_gain_one_and_the_prior_and_limit_hold_the_rest():
    """No statistics: gain 1. A node few pixels reached stays near 1 (the prior: 64
    pixel-weights of gain 1), and no gain leaves [1 / limit, limit]."""
    curve = GainCurve(bins=8, range=4.0, limit=2.0)
    out = _halves(0.3, 2.0)
    assert torch.equal(curve.apply(out, torch.zeros(1, 16)), out)
    stats = curve.statistics(out, 3.0 * out)
    gains = curve.gains(stats)[0]
    reached = stats[0, 8:] > 0
    assert torch.all(gains[~reached] == 1.0) and not bool(reached.all())
    assert torch.all(gains[reached] == 2.0)  # 3 x, limited to 2
    few = torch.full((1, 3, 2, 2), 0.3)  # 4 pixels whose label is 3 x
    (one,) = curve.gains(curve.statistics(few, 3.0 * few))[0][curve.nodes(few[:, :1])[0][0, :1]]
    assert 1.0 < float(one) < 1.3


def test_statistics_split_between_the_two_nearest_nodes():
    """A brightness between two nodes gives each its share (linear hat weights): nodes at
    u = 0, 1, 2, 3 (range 3, 4 bins); u = log1p(b) = 1.25 is 3/4 node 1, 1/4 node 2."""
    curve = GainCurve(bins=4, range=3.0, eps=1e-3, blur=0)
    b = float(np.expm1(1.25))
    out = torch.full((1, 3, 4, 4), b)
    stats = curve.statistics(out, out)[0]
    den = stats[4:]
    w_pixel = 3 * b * b / (b * b + 1e-3)  # sum over channels of w out^2, one pixel
    np.testing.assert_allclose(den.numpy(), [0, 0.75 * 16 * w_pixel, 0.25 * 16 * w_pixel, 0],
                               rtol=1e-5)  # fmt: skip


def test_the_curve_is_learned_state():
    """Through the model: a learning frame updates the statistics, a frozen one keeps them, a
    reset with `keep` carries them over and one without restarts them at zero."""
    model = build_model(
        "crossreg",
        {"widths": [4, 8], "regression_window": 9, "filter_window": 5, "gain_curve_bins": 8},
    )
    gen = torch.Generator().manual_seed(0)
    h = w = 16
    buffers = {
        "color": torch.rand(1, 3, h, w, generator=gen) ** 4,
        "color_b": torch.rand(1, 3, h, w, generator=gen) ** 4,
        "albedo": torch.rand(1, 3, h, w, generator=gen),
        "normal": torch.nn.functional.normalize(torch.rand(1, 3, h, w, generator=gen), dim=1),
        "depth": torch.ones(1, 1, h, w),
        "motion": torch.zeros(1, 2, h, w),
    }
    state = model.initial_state(1, h, w)
    with torch.no_grad():
        _, s1 = model(buffers, state, torch.tensor(1.0))
        learned = s1["gain_curve"].clone()
        assert float(learned.abs().sum()) > 0
        s1["freeze"] = torch.ones_like(s1["freeze"])
        out_frozen, s2 = model(buffers, s1, torch.tensor(0.0))
        assert torch.equal(s2["gain_curve"], learned)
        # the frozen frame shows the curve it has: brighter than the same frame without one
        plain, _ = model(
            buffers, {**s1, "gain_curve": torch.zeros_like(learned)}, torch.tensor(0.0)
        )
        assert not torch.equal(out_frozen, plain)
        s2["keep"] = torch.ones_like(s2["keep"])
        _, kept = model(buffers, s2, torch.tensor(1.0))
        assert torch.equal(kept["gain_curve"], learned)
        s2["keep"] = torch.zeros_like(s2["keep"])
        _, restarted = model(buffers, s2, torch.tensor(1.0))
        assert float(restarted["gain_curve"].abs().sum()) == 0.0


@pytest.mark.parametrize(
    "bad",
    [
        {"gain_curve_bins": 1},
        {"gain_curve_bins": 8, "gain_curve_decay": 1.0},
        {"gain_curve_bins": 8, "gain_curve_blur": -1},
    ],  # fmt: skip
)
def test_config_errors_name_the_gain_curve(bad):
    with pytest.raises(ValueError, match="gain_curve needs"):
        CrossRegConfig.of(bad)


def test_nan_and_inf_brightness_read_valid_nodes():
    """A NaN output (a diverged model's) reads node 0 and +inf the last: never an index out of
    range (ONNX Runtime's ScatterElements refuses one; the runtime then recovers the frame)."""
    curve = GainCurve(bins=8)
    out = torch.tensor([[[[float("nan"), float("inf"), 0.5, -1.0]]]]).expand(1, 3, 1, 4)
    lower, f = curve.nodes(out[:, :1])
    assert lower.tolist() == [[0, 6, 0, 0]] and float(f[0, 1]) == 1.0
    stats = curve.statistics(out, out)  # sums of NaN where the output is NaN: no error
    assert stats.shape == (1, 16)
