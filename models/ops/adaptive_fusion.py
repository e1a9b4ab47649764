"""AdaptiveFusion in torch form (Lee24 eq. (3)); defined in rtdenoise.ops.adaptive_fusion."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .torch_op import torch_op


def upsample2(x: torch.Tensor) -> torch.Tensor:
    """Nearest 2x upsampling U: out[..., y, x] = x[..., y // 2, x // 2]."""
    n, c, h, w = x.shape
    return x[:, :, :, None, :, None].expand(n, c, h, 2, w, 2).reshape(n, c, 2 * h, 2 * w)


@torch_op("AdaptiveFusion")
def adaptive_fusion(d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Fuse: d_ta (N, C, H, W), d_low (N, C, H/2, W/2), alpha (N, 1, H, W) -> (N, C, H, W).

    Differentiable tensor-op form (the numeric reference). Lee24 eq. (3).
    """
    # U is linear, so the two alpha terms merge (same evaluation order in all three forms).
    low_of_ta = F.avg_pool2d(d_ta, kernel_size=2, stride=2)
    return d_ta + alpha * upsample2(d_low - low_of_ta)
