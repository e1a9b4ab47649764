"""Reproject: warp the previous frame's tensors to the current pixels along the motion vectors.

out[n, c, y, x] = bilinear sample of previous[n, c] at (clamp(x + mx, 0, W - 1),
                  clamp(y + my, 0, H - 1)),   (mx, my) = motion[n, :, y, x]

or, with `nearest` = 1, the pixel nearest to that position, previous[n, c, floor(py + 0.5),
floor(px + 0.5)] with (px, py) the clamped position (Isik21's W_t, affinity's history warp;
a copy, so every form gives the same bits). `nearest` is optional: nodes exported before it
existed are bilinear.

Motion is in pixels, previous position = current position + motion (docs/contract.md); pixel
centres sit at integer coordinates; positions beyond the image read its border (the caller
rejects them with an in-bounds test). This is `grid_sample(previous, grid, "bilinear",
padding_mode="border", align_corners=False)` on the pixel grid moved by the motion, as one op:
the temporal accumulation of every family warps its history with it. Motion must be finite
(the runtime replaces NaN/Inf before the graph); non-finite motion gives an unspecified but
in-image sample in the fast kernel.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw


def _check(shapes, attrs) -> None:
    same_nhw("Reproject", shapes, ("previous", "motion"))
    if shapes[1][1] != 2:
        raise ValueError(f"Reproject: motion has {shapes[1][1]} channels; expected 2 (x, y)")
    if attrs["nearest"] not in (0, 1):
        raise ValueError(f"Reproject: nearest is {attrs['nearest']}; expected 0 or 1")


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """previous (N, C, H, W) in [0, 1) and motion mostly within 3 px, a few far off-screen."""
    n, c, h, w = shape
    previous = rng.random((n, c, h, w), dtype=np.float32)
    motion = rng.uniform(-3.0, 3.0, (n, 2, h, w)).astype(np.float32)
    far = rng.random((n, 1, h, w)) < 0.1
    motion = np.where(far, motion * 10.0, motion).astype(np.float32)
    return [previous, motion]


SPEC = OpSpec(
    name="Reproject",
    doc="out[n,c,y,x] = bilinear(previous[n,c], clamp(x+motion[n,0,y,x], 0, W-1), "
    "clamp(y+motion[n,1,y,x], 0, H-1)): the previous frame warped to the current pixels; "
    "nearest = 1: the pixel nearest to that position",
    inputs=(Arg("previous"), Arg("motion")),
    outputs=(Arg("output"),),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    attrs=("nearest",),
    default_attrs={"nearest": 0},
    example_attrs=({"nearest": 0}, {"nearest": 1}),
    optional_attrs={"nearest": 0},  # models exported before nearest existed
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 3, 13, 17), (2, 8, 8, 6), (1, 1, 1, 5)),
)
