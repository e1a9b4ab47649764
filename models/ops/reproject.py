"""Reproject in torch form; the op is defined in rtdenoise.ops.reproject."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .torch_op import torch_op


def pixel_grid(motion: torch.Tensor) -> torch.Tensor:
    """grid_sample coordinates (N, H, W, 2) of `current + motion` (align_corners=False)."""
    h, w = motion.shape[-2], motion.shape[-1]
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype)
    px = xs.view(1, 1, w) + motion[:, 0]  # previous x in pixels, (N, H, W)
    py = ys.view(1, h, 1) + motion[:, 1]
    # align_corners=False: pixel centre x maps to (2 x + 1) / W - 1.
    gx = (2.0 * px + 1.0) / w - 1.0
    gy = (2.0 * py + 1.0) / h - 1.0
    return torch.stack((gx, gy), dim=-1)


@torch_op("Reproject")
def reproject(previous: torch.Tensor, motion: torch.Tensor) -> torch.Tensor:
    """Bilinearly sample `previous` (N, C, H, W) at current + motion (border-clamped).

    Differentiable tensor-op form (the numeric reference).
    """
    return F.grid_sample(
        previous, pixel_grid(motion), mode="bilinear", padding_mode="border", align_corners=False
    )
