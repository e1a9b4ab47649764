"""AffinityFilter in torch form (Isik21 eq. (4), (6)); defined in rtdenoise.ops.affinity_filter.

`affinity_sums` is the one differentiable spelling of an affinity kernel's two sums (weighted
values and weights), shared with TemporalAffinityFilter. It works one row of taps at a time:
the k taps of a kernel row are a strided view (`unfold`) of the zero-padded row band, so a
13 x 13 kernel costs 13 steps of a few tensor ops, not 169.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rtdenoise.ops.affinity_filter import EPS, SPEC, kernel_size_value

from .torch_op import torch_op


def _tap_rows(x: torch.Tensor, k: int, d: int, i: int, h: int) -> torch.Tensor:
    """(N, C, H, W, k): the k taps of kernel row i, from x zero-padded by (k // 2) * d."""
    return x[:, :, i * d : i * d + h, :].unfold(3, (k - 1) * d + 1, 1)[..., ::d]


def affinity_sums(
    image: torch.Tensor,
    features: torch.Tensor,
    other_features: torch.Tensor,
    bandwidth: torch.Tensor,
    k: int,
    d: int,
    mask: torch.Tensor | None = None,
    centre: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(sum_q w_pq image_q, sum_q w_pq) over k x k taps q = p + (i - k//2, j - k//2) * d with
    w_pq = exp(-bandwidth_p ||features_p - other_features_q||^2) (Isik21 eq. (4) / (7)).

    Taps outside the image weigh 0; `mask` (N, 1, H, W) multiplies w_pq by mask_q; with
    `centre` (N, 1, H, W) the centre tap's weight is centre_p instead (eq. (4)).
    """
    n, _, h, w = image.shape
    r = k // 2
    p = r * d
    pad = (p, p, p, p)
    inside = torch.ones_like(bandwidth) if mask is None else mask
    x_pad = F.pad(image, pad)
    g_pad = F.pad(other_features, pad)
    m_pad = F.pad(inside, pad)
    f = features.unsqueeze(-1)
    a = bandwidth.unsqueeze(-1)
    num = image.new_zeros(image.shape)
    den = bandwidth.new_zeros(bandwidth.shape)
    for i in range(k):
        diff = f - _tap_rows(g_pad, k, d, i, h)
        weight = torch.exp(-a * (diff * diff).sum(dim=1, keepdim=True))
        weight = weight * _tap_rows(m_pad, k, d, i, h)
        if centre is not None and i == r:
            is_centre = torch.arange(k, device=image.device) == r
            weight = torch.where(is_centre, centre.unsqueeze(-1), weight)
        num = num + (weight * _tap_rows(x_pad, k, d, i, h)).sum(dim=-1)
        den = den + weight.sum(dim=-1)
    return num, den


@torch_op("AffinityFilter")
def affinity_filter_reference(
    image: torch.Tensor,
    features: torch.Tensor,
    bandwidth: torch.Tensor,
    centre: torch.Tensor,
    kernel_size: torch.Tensor,
    dilation: int,
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference). Isik21 eq. (4), (6)."""
    k = kernel_size_value(kernel_size.detach().cpu().numpy())
    num, den = affinity_sums(image, features, features, bandwidth, k, dilation, centre=centre)
    return num / (EPS + den)


def affinity_filter(
    image: torch.Tensor,
    features: torch.Tensor,
    bandwidth: torch.Tensor,
    centre: torch.Tensor,
    kernel_size: torch.Tensor,
    dilation: int = 1,
) -> torch.Tensor:
    """One dilated affinity kernel (Isik21 eq. (4), (6)): image (N, C, H, W), features
    (N, d, H, W), bandwidth a >= 0 and centre weight c (N, 1, H, W), kernel_size a float32
    scalar tensor (odd) -> (N, C, H, W).

    While autograd records on CPU it runs the numba forward / backward (affinity_autograd)."""
    from .affinity_autograd import AffinityFilterFunction, use_training_kernels

    tensors = (image, features, bandwidth, centre)
    if use_training_kernels(*tensors):
        SPEC.validate_call(
            [tuple(t.shape) for t in (*tensors, kernel_size)], {"dilation": dilation}
        )
        k = kernel_size_value(kernel_size.detach().cpu().numpy())
        return AffinityFilterFunction.apply(*tensors, k, dilation)
    return affinity_filter_reference(
        image, features, bandwidth, centre, kernel_size, dilation=dilation
    )
