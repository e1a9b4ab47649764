"""WeightSharingFilter in torch form (Fan21); defined in rtdenoise.ops.weight_sharing_filter."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from rtdenoise.ops.weight_sharing_filter import FAN21_SIZES, attrs_to_sizes, sizes_to_attrs

from .torch_op import torch_op


def _box_sum_scaled(x: torch.Tensor, s: int) -> torch.Tensor:
    """boxsum_s(x) / s^2 with zero padding (separable: 1 x s, then s x 1)."""
    r = s // 2
    x = F.avg_pool2d(x, (1, s), stride=1, padding=(0, r), count_include_pad=True)
    return F.avg_pool2d(x, (s, 1), stride=1, padding=(r, 0), count_include_pad=True)


@torch_op("WeightSharingFilter")
def weight_sharing_filter_reference(
    image: torch.Tensor, weights: torch.Tensor, size_min: int, size_step: int, count: int
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference)."""
    sizes = attrs_to_sizes(size_min, size_step, count)
    c = image.shape[1]
    blocks = []
    for i, s in enumerate(sizes):
        w = weights[:, i : i + 1]
        # numerator channels and the denominator in one pooling call (the 1/s^2 cancels)
        pooled = _box_sum_scaled(torch.cat([w * image, w], dim=1), s)
        num, den = pooled[:, :c], pooled[:, c:]
        positive = den > 0
        safe = torch.where(positive, den, torch.ones_like(den))  # no 0/0 in the unused branch
        blocks.append(torch.where(positive, num / safe, torch.zeros_like(num)))
    return torch.cat(blocks, dim=1)


def weight_sharing_filter(
    image: torch.Tensor, weights: torch.Tensor, sizes: Sequence[int] = FAN21_SIZES
) -> torch.Tensor:
    """Filter image (N, C, H, W) with one box per size: weights (N, S, H, W) >= 0 ->
    (N, S*C, H, W); block i is boxsum(w_i * image) / boxsum(w_i) over sizes[i] (Fan21)."""
    return weight_sharing_filter_reference(image, weights, **sizes_to_attrs(sizes))
