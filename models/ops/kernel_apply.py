"""KernelApply: apply a predicted per-pixel k x k kernel to an image (Lee24 eq. (2)).

out[n, c, y, x] = sum_{i, j < k} kernel[n, i*k + j, y, x]
                  * image[n, c, clamp_y(y + (i - r) d), clamp_x(x + (j - r) d)],  r = k // 2

Coordinates are clamped to the image (edge replicate); the kernel is applied as given (the
model normalises it, e.g. softmax over taps, before the call).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .registry import use_custom_op


def kernel_size_of(kernel: torch.Tensor) -> int:
    """k from a (N, k*k, H, W) kernel tensor; raises ValueError when k*k is not an odd square."""
    taps = int(kernel.shape[1])
    k = math.isqrt(taps)
    if k * k != taps or k % 2 == 0:
        raise ValueError(f"kernel has {taps} channels; expected k*k with k odd")
    return k


def _check(image: torch.Tensor, kernel: torch.Tensor, dilation: int) -> int:
    if image.dim() != 4 or kernel.dim() != 4:
        raise ValueError(
            f"kernel_apply expects 4-D tensors, got image {tuple(image.shape)} "
            f"and kernel {tuple(kernel.shape)}"
        )
    if dilation < 1:
        raise ValueError(f"dilation must be >= 1, got {dilation}")
    return kernel_size_of(kernel)


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


@torch.library.custom_op("rtdenoise::kernel_apply", mutates_args=())
def kernel_apply_op(
    image: torch.Tensor, kernel: torch.Tensor, kernel_size: int, dilation: int
) -> torch.Tensor:
    """Export form: one node `rtdenoise::kernel_apply` (ONNX `rtdenoise.KernelApply`)."""
    with torch.no_grad():
        return kernel_apply_reference(image, kernel, kernel_size, dilation).contiguous()


@kernel_apply_op.register_fake
def _(image: torch.Tensor, kernel: torch.Tensor, kernel_size: int, dilation: int) -> torch.Tensor:
    return image.new_empty(image.shape)


def kernel_apply(image: torch.Tensor, kernel: torch.Tensor, dilation: int = 1) -> torch.Tensor:
    """Apply per-pixel kernels: image (N, C, H, W), kernel (N, k*k, H, W) -> (N, C, H, W).

    k is read from kernel.shape[1] (odd k). Lee24 eq. (2); edge-clamped taps.
    """
    k = _check(image, kernel, dilation)
    if use_custom_op():
        return kernel_apply_op(image, kernel, k, int(dilation))
    return kernel_apply_reference(image, kernel, k, int(dilation))
