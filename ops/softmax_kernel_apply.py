"""SoftmaxKernelApply: KernelApply of per-pixel kernels given as logits (Lee24 eq. (2)).

out[n, c, y, x] = sum_{i, j < k} softmax_t(logits[n, :, y, x])[i*k + j]
                  * image[n, c, clamp(y + (i - r) d), clamp(x + (j - r) d)],  r = k // 2

= KernelApply(image, softmax over the k*k taps of logits): the softmax normalisation of Lee24's
predicted kernels inside the filter, so that the normalised k*k-channel kernel is never
written out (at 720p the spelled-out softmax over AFN's 49-tap full-scale kernel cost about
half of the whole frame in ONNX Runtime, benchmarks/README.md). Numerically stable (the
per-pixel maximum is subtracted).
"""

from __future__ import annotations

import numpy as np

from .kernel_apply import SPEC as KERNEL_APPLY
from .kernel_apply import kernel_check
from .spec import Arg, OpSpec


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """image (N, C, H, W) in [0, 1) and logits (N, k*k, H, W), standard normal times 3."""
    n, _, h, w = shape
    k = attrs["kernel_size"]
    image = rng.random(shape, dtype=np.float32)
    logits = 3.0 * rng.standard_normal((n, k * k, h, w), dtype=np.float32)
    return [image, logits.astype(np.float32)]


SPEC = OpSpec(
    name="SoftmaxKernelApply",
    doc="out[n,c,y,x] = sum_{i,j<k} softmax_t(logits[n,:,y,x])[i*k+j] * image[n,c,"
    "clamp(y+(i-k//2)*d), clamp(x+(j-k//2)*d)] (Lee24 eq. 2 with its softmax kernels)",
    inputs=(Arg("image"), Arg("logits")),
    outputs=(Arg("output"),),
    attrs=KERNEL_APPLY.attrs,
    output_shapes=KERNEL_APPLY.output_shapes,
    check=kernel_check("SoftmaxKernelApply", "logits"),
    example_inputs=_example_inputs,
    default_attrs=KERNEL_APPLY.default_attrs,
    example_attrs=KERNEL_APPLY.example_attrs,
)
