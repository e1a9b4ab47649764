"""KernelFusion: blend S filtered images with per-pixel softmax weights (Fan21 kernel fusion).

out[n, c] = sum_i softmax_i(logits[n])[i] * images[n, i*C + c],  C = channels(images) / S

The softmax runs over the S logits of each pixel (numerically stable: max subtracted).
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw

EXAMPLE_SIZES = 6  # Fan21: six filtered images


def _check(shapes, attrs) -> None:
    same_nhw("KernelFusion", shapes, ("images", "logits"))
    sc, s = shapes[0][1], shapes[1][1]
    if s < 1 or sc % s:
        raise ValueError(
            f"KernelFusion: images {tuple(shapes[0])} and logits {tuple(shapes[1])}: expected "
            "(N, S*C, H, W) and (N, S, H, W)"
        )


def _output_shapes(shapes, attrs):
    (n, sc, h, w), s = shapes[0], shapes[1][1]
    return [(n, sc // s, h, w)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """images (N, 6*C, H, W) in [0, 1) and logits (N, 6, H, W) ~ 2 * normal, for an output
    shape (N, C, H, W)."""
    n, c, h, w = shape
    s = EXAMPLE_SIZES
    images = rng.random((n, s * c, h, w), dtype=np.float32)
    logits = (2.0 * rng.standard_normal((n, s, h, w), dtype=np.float32)).astype(np.float32)
    return [images, logits]


SPEC = OpSpec(
    name="KernelFusion",
    doc="out[:, c] = sum_i softmax_i(logits)[i] * images[:, i*C + c], C = channels / S (Fan21)",
    inputs=(Arg("images"), Arg("logits")),
    outputs=(Arg("output"),),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
)
