"""KernelFusion in torch form (Fan21 kernel fusion); defined in rtdenoise.ops.kernel_fusion."""

from __future__ import annotations

import torch

from ..functional import channel_softmax
from .torch_op import torch_op


@torch_op("KernelFusion")
def kernel_fusion(images: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
    """Fuse images (N, S*C, H, W) with softmax(logits (N, S, H, W)) over S -> (N, C, H, W).

    Differentiable tensor-op form (the numeric reference).
    """
    n, sc, h, w = images.shape
    s = logits.shape[1]
    p = channel_softmax(logits)
    return (p.unsqueeze(2) * images.reshape(n, s, sc // s, h, w)).sum(dim=1)
