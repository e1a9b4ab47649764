"""KernelApply in torch form (Lee24 eq. (2)); the op is defined in rtdenoise.ops.kernel_apply."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rtdenoise.ops.kernel_apply import kernel_size_of

from .torch_op import torch_op


@torch_op("KernelApply")
def kernel_apply_reference(
    image: torch.Tensor, kernel: torch.Tensor, kernel_size: int, dilation: int
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference). Lee24 eq. (2)."""
    k, d = kernel_size, dilation
    n, c, h, w = image.shape
    p = (k // 2) * d
    # Replicate padding equals clamping the coordinates, for any pad size.
    padded = F.pad(image, (p, p, p, p), mode="replicate")
    out = None
    for i in range(k):
        for j in range(k):
            t = i * k + j
            shifted = padded[:, :, i * d : i * d + h, j * d : j * d + w]
            term = kernel[:, t : t + 1] * shifted
            out = term if out is None else out + term
    return out


def kernel_apply(image: torch.Tensor, kernel: torch.Tensor, dilation: int = 1) -> torch.Tensor:
    """Apply per-pixel kernels: image (N, C, H, W), kernel (N, k*k, H, W) -> (N, C, H, W).

    k is read from kernel.shape[1] (odd k). Lee24 eq. (2); edge-clamped taps.
    """
    k = kernel_size_of(kernel.shape[1]) if kernel.dim() == 4 else 0
    return kernel_apply_reference(image, kernel, kernel_size=k, dilation=dilation)
