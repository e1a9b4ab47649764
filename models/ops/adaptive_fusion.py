"""AdaptiveFusion: replace the low frequencies of the accumulated image (Lee24 eq. (3)).

out = d_ta - alpha * U(D(d_ta)) + alpha * U(d_low) = d_ta + alpha * U(d_low - D(d_ta))

D is 2 x 2 average pooling (stride 2), U is nearest 2x upsampling. H and W must be even
(the model pads its inputs to `pad_multiple`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .registry import use_custom_op


def _check(d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor) -> None:
    if d_ta.dim() != 4 or d_low.dim() != 4 or alpha.dim() != 4:
        raise ValueError("adaptive_fusion expects 4-D tensors")
    n, c, h, w = d_ta.shape
    if h % 2 or w % 2:
        raise ValueError(f"adaptive_fusion needs even H and W, got {h}x{w}")
    if tuple(d_low.shape) != (n, c, h // 2, w // 2):
        raise ValueError(f"d_low has shape {tuple(d_low.shape)}; expected {(n, c, h // 2, w // 2)}")
    if tuple(alpha.shape) != (n, 1, h, w):
        raise ValueError(f"alpha has shape {tuple(alpha.shape)}; expected {(n, 1, h, w)}")


def upsample2(x: torch.Tensor) -> torch.Tensor:
    """Nearest 2x upsampling U: out[..., y, x] = x[..., y // 2, x // 2]."""
    n, c, h, w = x.shape
    return x[:, :, :, None, :, None].expand(n, c, h, 2, w, 2).reshape(n, c, 2 * h, 2 * w)


def adaptive_fusion_reference(
    d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference). Lee24 eq. (3)."""
    # U is linear, so the two alpha terms merge (same evaluation order in all three forms).
    low_of_ta = F.avg_pool2d(d_ta, kernel_size=2, stride=2)
    return d_ta + alpha * upsample2(d_low - low_of_ta)


@torch.library.custom_op("rtdenoise::adaptive_fusion", mutates_args=())
def adaptive_fusion_op(
    d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor
) -> torch.Tensor:
    """Export form: one node `rtdenoise::adaptive_fusion` (ONNX `rtdenoise.AdaptiveFusion`)."""
    with torch.no_grad():
        return adaptive_fusion_reference(d_ta, d_low, alpha).contiguous()


@adaptive_fusion_op.register_fake
def _(d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    return d_ta.new_empty(d_ta.shape)


def adaptive_fusion(d_ta: torch.Tensor, d_low: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Fuse: d_ta (N, C, H, W), d_low (N, C, H/2, W/2), alpha (N, 1, H, W) -> (N, C, H, W)."""
    _check(d_ta, d_low, alpha)
    if use_custom_op():
        return adaptive_fusion_op(d_ta, d_low, alpha)
    return adaptive_fusion_reference(d_ta, d_low, alpha)
