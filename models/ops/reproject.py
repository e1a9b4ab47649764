"""Reproject in torch form; the op is defined in rtdenoise.ops.reproject."""

from __future__ import annotations

import torch

from .torch_op import torch_op


def clamped_position(motion: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For every pixel of (N, 2, H, W) motion: its previous position (px, py), each (N, H, W),
    clamped to the image."""
    _, _, h, w = motion.shape
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype).view(1, 1, w)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype).view(1, h, 1)
    return torch.clamp(xs + motion[:, 0], 0.0, w - 1.0), torch.clamp(
        ys + motion[:, 1], 0.0, h - 1.0
    )


def bilinear_taps(motion: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """For every pixel of (N, 2, H, W) motion: the flat indices of its four taps (N, H*W each,
    nw, ne, sw, se) in an H*W plane and the weights (wx, wy) of the clamped source position."""
    n, _, h, w = motion.shape
    px, py = clamped_position(motion)
    x0, y0 = torch.floor(px), torch.floor(py)
    wx, wy = px - x0, py - y0
    x0i, y0i = x0.long(), y0.long()
    x1i, y1i = torch.clamp(x0i + 1, max=w - 1), torch.clamp(y0i + 1, max=h - 1)
    taps = [
        (yi * w + xi).reshape(n, h * w)
        for yi, xi in ((y0i, x0i), (y0i, x1i), (y1i, x0i), (y1i, x1i))
    ]
    return (*taps, wx, wy)


def nearest_tap(motion: torch.Tensor) -> torch.Tensor:
    """For every pixel of (N, 2, H, W) motion: the flat index (N, H*W) in an H*W plane of the
    pixel nearest to the clamped source position, floor(p + 0.5) on each axis."""
    n, _, h, w = motion.shape
    px, py = clamped_position(motion)
    return (torch.floor(py + 0.5).long() * w + torch.floor(px + 0.5).long()).reshape(n, h * w)


@torch_op("Reproject")
def reproject(previous: torch.Tensor, motion: torch.Tensor, nearest: int = 0) -> torch.Tensor:
    """Bilinearly sample `previous` (N, C, H, W) at current + motion, clamped to the image,
    or (`nearest` = 1) read the pixel nearest to that position.

    Differentiable tensor-op form (the numeric reference): four gathers weighted
    nw (1 - wy)(1 - wx) + ne (1 - wy) wx + sw wy (1 - wx) + se wy wx, summed in that order,
    the arithmetic the function body and the fast kernel repeat step by step; one gather
    for `nearest`.
    """
    n, c, h, w = previous.shape
    flat = previous.reshape(n, c, h * w)

    def tap(index: torch.Tensor) -> torch.Tensor:
        return torch.gather(flat, 2, index.unsqueeze(1).expand(n, c, h * w)).reshape(n, c, h, w)

    if nearest:
        return tap(nearest_tap(motion))
    *taps, wx, wy = bilinear_taps(motion)

    ex, ey = (1.0 - wx).unsqueeze(1), (1.0 - wy).unsqueeze(1)
    wx, wy = wx.unsqueeze(1), wy.unsqueeze(1)
    nw, ne, sw, se = (tap(t) for t in taps)
    return nw * (ey * ex) + ne * (ey * wx) + sw * (wy * ex) + se * (wy * wx)
