"""KernelApply: apply a predicted per-pixel k x k kernel to an image (Lee24 eq. (2)).

out[n, c, y, x] = sum_{i, j < k} kernel[n, i*k + j, y, x]
                  * image[n, c, clamp(y + (i - r) d), clamp(x + (j - r) d)],  r = k // 2

Coordinates are clamped to the image (edge replicate); the kernel is applied as given (the
model normalises it, e.g. softmax over taps, before the call).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .spec import Arg, OpSpec, same_nhw


def kernel_size_of(taps: int) -> int:
    """k from the k*k channels of a kernel tensor; ValueError unless k*k with k odd."""
    k = math.isqrt(int(taps))
    if k * k != int(taps) or k % 2 == 0:
        raise ValueError(f"KernelApply: kernel has {taps} channels; expected k*k with k odd")
    return k


def kernel_check(op: str, kernel: str) -> Callable[[list, dict], None]:
    """The `check` of an op applying per-pixel k x k kernels (its input 1, named `kernel`, has
    k*k channels) to its input 0, `image`: odd k, dilation >= 1, the same N, H, W."""

    def check(shapes, attrs) -> None:
        k, d = attrs["kernel_size"], attrs["dilation"]
        if k < 1 or k % 2 == 0 or d < 1:
            raise ValueError(f"{op} needs odd kernel_size and dilation >= 1, got {k}, {d}")
        same_nhw(op, shapes, ("image", kernel))
        if shapes[1][1] != k * k:
            raise ValueError(
                f"{op}: {kernel} has {shapes[1][1]} channels; expected kernel_size^2 = {k * k}"
            )

    return check


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """image (N, C, H, W) in [0, 1) and a softmax-normalised kernel (N, k*k, H, W)."""
    n, _, h, w = shape
    k = attrs["kernel_size"]
    image = rng.random(shape, dtype=np.float32)
    logits = rng.standard_normal((n, k * k, h, w), dtype=np.float32)
    kernel = np.exp(logits - logits.max(axis=1, keepdims=True))
    kernel /= kernel.sum(axis=1, keepdims=True)
    return [image, kernel.astype(np.float32)]


SPEC = OpSpec(
    name="KernelApply",
    doc="out[n,c,y,x] = sum_{i,j<k} kernel[n,i*k+j,y,x] * image[n,c,clamp(y+(i-k//2)*d),"
    " clamp(x+(j-k//2)*d)] (Lee24 eq. 2)",
    inputs=(Arg("image"), Arg("kernel")),
    outputs=(Arg("output"),),
    attrs=("kernel_size", "dilation"),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    check=kernel_check("KernelApply", "kernel"),
    example_inputs=_example_inputs,
    default_attrs={"kernel_size": 7, "dilation": 1},
    example_attrs=(
        {"kernel_size": 3, "dilation": 1},
        {"kernel_size": 5, "dilation": 2},
        {"kernel_size": 7, "dilation": 3},
    ),
)
