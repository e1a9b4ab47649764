"""TemporalAffinityFilter in torch form (Isik21 eq. (7)-(8)); defined in
rtdenoise.ops.temporal_affinity_filter."""

from __future__ import annotations

import torch

from rtdenoise.ops.affinity_filter import EPS, kernel_size_value
from rtdenoise.ops.temporal_affinity_filter import SPEC

from .affinity_filter import affinity_sums
from .torch_op import torch_op


@torch_op("TemporalAffinityFilter")
def temporal_affinity_filter_reference(
    image: torch.Tensor,
    features: torch.Tensor,
    bandwidth: torch.Tensor,
    centre: torch.Tensor,
    previous: torch.Tensor,
    previous_features: torch.Tensor,
    temporal_bandwidth: torch.Tensor,
    valid: torch.Tensor,
    kernel_size: torch.Tensor,
    temporal_size: torch.Tensor,
    dilation: int,
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference). Isik21 eq. (8): the last spatial
    kernel (eq. (4)) and the temporal kernel (eq. (7)) normalised jointly."""
    op = "TemporalAffinityFilter"
    k = kernel_size_value(kernel_size.detach().cpu().numpy(), op)
    kt = kernel_size_value(temporal_size.detach().cpu().numpy(), op)
    num, den = affinity_sums(image, features, features, bandwidth, k, dilation, centre=centre)
    t_num, t_den = affinity_sums(
        previous, features, previous_features, temporal_bandwidth, kt, 1, mask=valid
    )
    return (num + t_num) / (EPS + den + t_den)


def temporal_affinity_filter(
    image: torch.Tensor,
    features: torch.Tensor,
    bandwidth: torch.Tensor,
    centre: torch.Tensor,
    previous: torch.Tensor,
    previous_features: torch.Tensor,
    temporal_bandwidth: torch.Tensor,
    valid: torch.Tensor,
    kernel_size: torch.Tensor,
    temporal_size: torch.Tensor,
    dilation: int = 1,
) -> torch.Tensor:
    """Isik21 eq. (8): the last spatial kernel and the temporal kernel over the warped
    previous output, normalised jointly (shapes: rtdenoise.ops.temporal_affinity_filter).

    While autograd records on CPU it runs the numba forward / backward (affinity_autograd)."""
    from .affinity_autograd import TemporalAffinityFilterFunction, use_training_kernels

    tensors = (
        image, features, bandwidth, centre, previous, previous_features, temporal_bandwidth,
        valid,
    )  # fmt: skip
    if use_training_kernels(*tensors):
        sizes = (kernel_size, temporal_size)
        shapes = [tuple(t.shape) for t in (*tensors, *sizes)]
        SPEC.validate_call(shapes, {"dilation": dilation})
        op = SPEC.name
        k, kt = (kernel_size_value(s.detach().cpu().numpy(), op) for s in sizes)
        return TemporalAffinityFilterFunction.apply(*tensors, k, kt, dilation)
    return temporal_affinity_filter_reference(
        *tensors, kernel_size, temporal_size, dilation=dilation
    )
