"""Exposure and a perceptual transfer curve for HDR losses (after Open Image Denoise's recipe).

OIDN trains its HDR networks on colours scaled by an auto-exposure, then mapped through a
perceptually uniform (PU) transfer curve (Aydin et al. 2008, "Extending quality metrics to full
luminance range images"), and computes its loss there. This module is this project's own form
of both ideas, not OIDN's constants:

- `autoexposure`: key / geometric mean of the luminance of 16 x 16-pixel block averages (blocks
  darker than 1e-8 left out), key = 0.18 (the photographic middle grey, Reinhard et al. 2002),
  so that a dim and a bright render of one scene map to the same values.
- `perceptual_transfer` ("PU-like"): the sRGB transfer curve (IEC 61966-2-1: linear toe
  12.92 x below 0.0031308, 1.055 x^(1/2.4) - 0.055 above) up to 1, continued above 1 by the
  logarithm with the same slope at 1, T(x) = 1 + (1.055 / 2.4) ln x, so that it is C1 at 1,
  perceptually spaced in the display range and never saturates on highlights (65504 -> 5.87;
  the metric curve tau(x) = (x / (1 + x))^(1/2.4) of Isik21 eq. (14) flattens above 1, which
  would leave small bright lights almost free to smear). Odd-symmetric for negative inputs, so
  a model's negative outputs still get a gradient back to 0.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

# Rec. 709 / sRGB luminance weights (ITU-R BT.709).
LUMINANCE = (0.2126, 0.7152, 0.0722)
KEY = 0.18
EXPOSURE_BLOCK = 16
EXPOSURE_EPS = 1e-8

_TOE = 0.0031308
_SLOPE_AT_ONE = 1.055 / 2.4


def luminance(x: torch.Tensor) -> torch.Tensor:
    """(..., 3, H, W) linear RGB -> (..., H, W) luminance (Rec. 709 weights)."""
    w = x.new_tensor(LUMINANCE).view(3, 1, 1)
    return (x * w).sum(dim=-3)


def autoexposure(
    x: torch.Tensor, key: float = KEY, block: int = EXPOSURE_BLOCK, eps: float = EXPOSURE_EPS
) -> torch.Tensor:
    """Exposure factor per leading index of (B, ..., 3, H, W) linear RGB: key / geometric mean
    of the luminance of block x block averages over everything after B (all frames of a clip).

    A block side larger than the image shrinks to the image; 1 where no block is brighter than
    `eps` (a black clip). No gradient flows through it. Returns (B,) float32.
    """
    with torch.no_grad():
        lum = luminance(x.float())  # (B, ..., H, W)
        b, (h, w) = lum.shape[0], lum.shape[-2:]
        side = max(1, min(block, h, w))
        flat = lum.reshape(-1, 1, h, w)
        means = F.avg_pool2d(flat, side, stride=side, ceil_mode=True).reshape(b, -1)
        bright = means > eps
        logs = torch.where(bright, torch.log(means.clamp_min(eps)), torch.zeros_like(means))
        count = bright.sum(dim=1)
        gmean = torch.exp(logs.sum(dim=1) / count.clamp_min(1))
        return torch.where(count > 0, key / gmean, torch.ones_like(gmean))


def perceptual_transfer(x: torch.Tensor) -> torch.Tensor:
    """The PU-like curve of the module docstring, elementwise: sRGB below 1, 1 + 0.4396 ln x
    above, sign(x) T(|x|) for x < 0. T(0) = 0, T(1) = 1, T(65504) = 5.87."""
    a = x.abs()
    sign = torch.where(x < 0, -1.0, 1.0)
    mid = 1.055 * a.clamp_min(_TOE).pow(1.0 / 2.4) - 0.055
    top = 1.0 + _SLOPE_AT_ONE * torch.log(a.clamp_min(1.0))
    # the toe on x itself (odd, slope 12.92 at 0: a gradient even for an output of exactly 0)
    return torch.where(a <= _TOE, 12.92 * x, sign * torch.where(a <= 1.0, mid, top))


def exposed_transfer(
    outputs: torch.Tensor, reference: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """(T(e x_out), T(e x_ref)) for (B, ..., 3, H, W) clips, e = autoexposure of each clip's
    reference (so the loss weighs a dim clip like a bright one)."""
    e = autoexposure(reference).view(-1, *([1] * (reference.dim() - 1)))
    return perceptual_transfer(outputs * e), perceptual_transfer(reference * e)


__all__ = [
    "KEY",
    "LUMINANCE",
    "autoexposure",
    "exposed_transfer",
    "luminance",
    "perceptual_transfer",
]
