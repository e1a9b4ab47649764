"""AdaptiveFusion: replace the low frequencies of the accumulated image (Lee24 eq. (3)).

out = d_ta - alpha * U(D(d_ta)) + alpha * U(d_low) = d_ta + alpha * U(d_low - D(d_ta))

D is 2 x 2 average pooling (stride 2), U is nearest 2x upsampling. H and W must be even
(the model pads its inputs to `pad_multiple`).
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec


def _check(shapes, attrs) -> None:
    (n, c, h, w), low, alpha = shapes
    if h % 2 or w % 2:
        raise ValueError(f"AdaptiveFusion needs even H and W, got {h}x{w}")
    if tuple(low) != (n, c, h // 2, w // 2):
        raise ValueError(
            f"AdaptiveFusion: d_low has shape {tuple(low)}; expected {(n, c, h // 2, w // 2)}"
        )
    if tuple(alpha) != (n, 1, h, w):
        raise ValueError(f"AdaptiveFusion: alpha has shape {tuple(alpha)}; expected {(n, 1, h, w)}")


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """d_ta (N, C, H, W), d_low (N, C, H/2, W/2) in [0, 1) and alpha (N, 1, H, W) in [0, 1)."""
    n, c, h, w = shape
    return [
        rng.random((n, c, h, w), dtype=np.float32),
        rng.random((n, c, h // 2, w // 2), dtype=np.float32),
        rng.random((n, 1, h, w), dtype=np.float32),
    ]


SPEC = OpSpec(
    name="AdaptiveFusion",
    doc="out = d_ta - alpha * U(D(d_ta)) + alpha * U(d_low), D = 2x2 mean, U = nearest x2"
    " (Lee24 eq. 3)",
    inputs=(Arg("d_ta"), Arg("d_low"), Arg("alpha")),
    outputs=(Arg("output"),),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 3, 14, 18), (2, 1, 2, 2), (1, 5, 8, 34)),
)
