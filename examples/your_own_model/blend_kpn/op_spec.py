"""NeighbourBlend: out = image + weight * (box3x3(image) - image), the 3 x 3 mean with the
image's edge replicated; weight (N, 1, H, W) per pixel. Declared once, no torch or onnx."""

from __future__ import annotations

import numpy as np

from rtdenoise.ops import Arg, OpSpec, register_spec
from rtdenoise.ops.spec import same_nhw


def _check(shapes, attrs) -> None:
    same_nhw("NeighbourBlend", shapes, ("image", "weight"))
    if shapes[1][1] != 1:
        raise ValueError(f"NeighbourBlend: weight has {shapes[1][1]} channels; expected 1")


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    n, c, h, w = shape
    return [rng.random((n, c, h, w), dtype=np.float32), rng.random((n, 1, h, w), dtype=np.float32)]


SPEC = register_spec(  # found by its entry point when installed; registered here when not
    OpSpec(
        name="NeighbourBlend",
        doc="out = image + weight * (box3x3(image) - image), edges replicated",
        inputs=(Arg("image"), Arg("weight")),
        outputs=(Arg("output"),),
        output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
        check=_check,
        example_inputs=_example_inputs,
    )
)
