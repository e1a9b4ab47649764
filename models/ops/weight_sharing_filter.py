"""WeightSharingFilter: Fan21's weight-sharing kernels, several box sizes at once.

For box size s_i = size_min + i * size_step (i < count; odd sizes) and importance map w_i:

    out_i = boxsum_{s_i}(w_i * image) / boxsum_{s_i}(w_i)      (0 where boxsum_{s_i}(w_i) <= 0)

boxsum_s is the sum over the s x s window centred on the pixel, restricted to in-bounds pixels
(zero padding of numerator and denominator). One importance map per size is shared by all the
window's taps: the weight of tap q for pixel p is w_i(q) / sum_window w_i (Fan21). Output block
i holds channels i*C .. i*C + C - 1. Weights are >= 0 (the model feeds exp(...)).

The sizes travel as three int attributes (size_min, size_step, count) because ONNX Runtime
extension ops take no list attributes; `sizes_to_attrs` converts an arithmetic list of odd
sizes, e.g. Fan21's [3, 5, 7, 9, 11, 13] -> (3, 2, 6).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F

from .registry import use_custom_op

FAN21_SIZES = (3, 5, 7, 9, 11, 13)


def sizes_to_attrs(sizes: Sequence[int]) -> dict[str, int]:
    """{size_min, size_step, count} for an arithmetic list of odd box sizes; else ValueError."""
    sizes = [int(s) for s in sizes]
    if not sizes:
        raise ValueError("weight_sharing_filter needs at least one box size")
    step = sizes[1] - sizes[0] if len(sizes) > 1 else 2
    attrs = {"size_min": sizes[0], "size_step": step, "count": len(sizes)}
    if sizes != attrs_to_sizes(**attrs):
        raise ValueError(
            f"box sizes must be odd, >= 1 and evenly spaced (s0 + i*step), got {sizes}"
        )
    return attrs


def attrs_to_sizes(size_min: int, size_step: int, count: int) -> list[int]:
    """The box sizes [size_min + i * size_step for i < count]; ValueError unless all odd >= 1."""
    if count < 1 or size_min < 1 or size_min % 2 == 0 or size_step < 0 or size_step % 2:
        raise ValueError(
            f"need count >= 1, odd size_min >= 1 and even size_step >= 0, "
            f"got size_min={size_min}, size_step={size_step}, count={count}"
        )
    return [size_min + i * size_step for i in range(count)]


def _box_sum_scaled(x: torch.Tensor, s: int) -> torch.Tensor:
    """boxsum_s(x) / s^2 with zero padding (separable: 1 x s, then s x 1)."""
    r = s // 2
    x = F.avg_pool2d(x, (1, s), stride=1, padding=(0, r), count_include_pad=True)
    return F.avg_pool2d(x, (s, 1), stride=1, padding=(r, 0), count_include_pad=True)


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


@torch.library.custom_op("rtdenoise::weight_sharing_filter", mutates_args=())
def weight_sharing_filter_op(
    image: torch.Tensor, weights: torch.Tensor, size_min: int, size_step: int, count: int
) -> torch.Tensor:
    """Export form: one node `rtdenoise::weight_sharing_filter` (ONNX WeightSharingFilter)."""
    with torch.no_grad():
        return weight_sharing_filter_reference(
            image, weights, size_min, size_step, count
        ).contiguous()


@weight_sharing_filter_op.register_fake
def _(
    image: torch.Tensor, weights: torch.Tensor, size_min: int, size_step: int, count: int
) -> torch.Tensor:
    n, c, h, w = image.shape
    return image.new_empty((n, count * c, h, w))


def _check(image: torch.Tensor, weights: torch.Tensor, count: int) -> None:
    if image.dim() != 4 or weights.dim() != 4:
        raise ValueError(
            f"weight_sharing_filter expects 4-D tensors, got image {tuple(image.shape)} "
            f"and weights {tuple(weights.shape)}"
        )
    n, _, h, w = image.shape
    if tuple(weights.shape) != (n, count, h, w):
        raise ValueError(
            f"weights have shape {tuple(weights.shape)}; expected {(n, count, h, w)} "
            "(one importance map per box size)"
        )


def weight_sharing_filter(
    image: torch.Tensor, weights: torch.Tensor, sizes: Sequence[int] = FAN21_SIZES
) -> torch.Tensor:
    """Filter image (N, C, H, W) with one box per size: weights (N, S, H, W) >= 0 ->
    (N, S*C, H, W); block i is boxsum(w_i * image) / boxsum(w_i) over sizes[i] (Fan21)."""
    attrs = sizes_to_attrs(sizes)
    _check(image, weights, attrs["count"])
    if use_custom_op():
        return weight_sharing_filter_op(image, weights, **attrs)
    return weight_sharing_filter_reference(image, weights, **attrs)
