"""KernelFusion: blend S filtered images with per-pixel softmax weights (Fan21 kernel fusion).

out[n, c] = sum_i softmax_i(logits[n])[i] * images[n, i*C + c],  C = channels(images) / S

The softmax runs over the S logits of each pixel (numerically stable: max subtracted).
"""

from __future__ import annotations

import torch

from ..functional import channel_softmax
from .registry import use_custom_op


def _check(images: torch.Tensor, logits: torch.Tensor) -> int:
    """C = channels(images) / S, or ValueError."""
    if images.dim() != 4 or logits.dim() != 4:
        raise ValueError(
            f"kernel_fusion expects 4-D tensors, got images {tuple(images.shape)} "
            f"and logits {tuple(logits.shape)}"
        )
    n, sc, h, w = images.shape
    s = logits.shape[1]
    if s < 1 or sc % s or tuple(logits.shape) != (n, s, h, w):
        raise ValueError(
            f"images {tuple(images.shape)} and logits {tuple(logits.shape)}: expected "
            "(N, S*C, H, W) and (N, S, H, W)"
        )
    return sc // s


def kernel_fusion_reference(images: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference)."""
    n, sc, h, w = images.shape
    s = logits.shape[1]
    p = channel_softmax(logits)
    return (p.unsqueeze(2) * images.reshape(n, s, sc // s, h, w)).sum(dim=1)


@torch.library.custom_op("rtdenoise::kernel_fusion", mutates_args=())
def kernel_fusion_op(images: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    """Export form: one node `rtdenoise::kernel_fusion` (ONNX `rtdenoise.KernelFusion`)."""
    with torch.no_grad():
        return kernel_fusion_reference(images, logits).contiguous()


@kernel_fusion_op.register_fake
def _(images: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    n, sc, h, w = images.shape
    return images.new_empty((n, sc // logits.shape[1], h, w))


def kernel_fusion(images: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    """Fuse images (N, S*C, H, W) with softmax(logits (N, S, H, W)) over S -> (N, C, H, W)."""
    _check(images, logits)
    if use_custom_op():
        return kernel_fusion_op(images, logits)
    return kernel_fusion_reference(images, logits)
