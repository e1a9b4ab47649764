"""SoftmaxKernelApply in torch form (Lee24 eq. (2) on softmax kernels); the op is defined in
rtdenoise.ops.softmax_kernel_apply."""

from __future__ import annotations

import torch

from rtdenoise.ops.kernel_apply import kernel_size_of

from ..functional import channel_softmax
from .kernel_apply import kernel_apply_reference
from .torch_op import torch_op


@torch_op("SoftmaxKernelApply")
def softmax_kernel_apply_reference(
    image: torch.Tensor, logits: torch.Tensor, kernel_size: int, dilation: int
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference): softmax over the taps, then
    KernelApply's reference."""
    kernel = channel_softmax(logits)
    return kernel_apply_reference.reference(
        image, kernel, kernel_size=kernel_size, dilation=dilation
    )


def softmax_kernel_apply(
    image: torch.Tensor, logits: torch.Tensor, dilation: int = 1
) -> torch.Tensor:
    """Apply per-pixel kernels softmax(logits) over dim 1: image (N, C, H, W), logits
    (N, k*k, H, W) -> (N, C, H, W). k is read from logits.shape[1] (odd k)."""
    k = kernel_size_of(logits.shape[1]) if logits.dim() == 4 else 0
    return softmax_kernel_apply_reference(image, logits, kernel_size=k, dilation=dilation)
