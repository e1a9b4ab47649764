"""SvgfReproject: the previous frame's state warped to the current pixels with SVGF's per-tap
tests (Schied17 s.4.1, as Falcor's SVGFReproject and Choi24's official code do it): crossreg's
history warp.

Per pixel p = (x + mx, y + my) (motion in pixels, docs/contract.md). A tap t (integer position,
as float) passes when it lies in [0, W - 1] x [0, H - 1] and agrees with the current pixel:

    |depth_prev[t] - depth| <= depth_threshold (fwidth_z + 1e-2)
    ||normal_prev[t] - normal|| <= normal_threshold (fwidth_n + 1e-2)

fwidth_z = max(|dz/dx|, |dz/dy|), fwidth_n = || |dn/dx| + |dn/dy| || (forward differences, the
last row / column repeating its neighbour's). The four bilinear taps around p are weighted
(1 - ax)(1 - ay), ax (1 - ay), (1 - ax) ay, ax ay and renormalised over those that pass; valid
where they weigh >= 0.01. With `fallback` = 1, an invalid pixel with any passing tap in the 3 x 3
block around round(p) takes their plain mean. With `erode` = 1 the validity mask is eroded by
a 3 x 3 minimum (out-of-image neighbours ignored). Outputs: warped * mask and mask (1 / 0).

prev_geometry holds the previous normal (3) and depth (1); an out-of-image tap reads the
clamped pixel and is rejected. The whole warp as one op: spelled in standard ops it was about
300 nodes of a crossreg frame (gathers, comparisons, Where, a max pool).
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, example_geometry, same_nhw

IMAGES = ("previous", "prev_geometry", "motion", "normal", "depth")
SCALARS = ("depth_threshold", "normal_threshold")


def _check(shapes, attrs) -> None:
    for a in ("fallback", "erode"):
        if attrs[a] not in (0, 1):
            raise ValueError(f"SvgfReproject: {a} is {attrs[a]}; expected 0 or 1")
    same_nhw("SvgfReproject", shapes[: len(IMAGES)], IMAGES)
    expected = {"prev_geometry": 4, "motion": 2, "normal": 3, "depth": 1}
    for name, shape in zip(IMAGES[1:], shapes[1 : len(IMAGES)], strict=True):
        if shape[1] != expected[name]:
            raise ValueError(
                f"SvgfReproject: {name} has {shape[1]} channels; expected {expected[name]}"
            )
    if shapes[0][2] < 2 or shapes[0][3] < 2:
        raise ValueError(f"SvgfReproject: image {tuple(shapes[0])} is below 2 x 2 (fwidth)")


def _output_shapes(shapes, attrs) -> list:
    n, c, h, w = shapes[0]
    return [(n, c, h, w), (n, 1, h, w)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """A history that agrees with the frame on most pixels: smooth depth and normals, the
    previous geometry equal to them but on a quarter of the pixels (another normal, depth +1),
    motion mostly within 2 px (some off-screen), some exactly integer (taps on pixel centres)."""
    n, c, h, w = shape
    f32 = np.float32
    depth, normal, agree = example_geometry(shape, rng)
    prev_geometry = np.concatenate(
        [np.where(agree, normal, normal[:, ::-1]), np.where(agree, depth, depth + 1.0)], axis=1
    ).astype(f32)
    motion = rng.uniform(-2.0, 2.0, (n, 2, h, w))
    motion = np.where(rng.random((n, 1, h, w)) < 0.1, 10.0 * motion, motion)
    motion = np.where(rng.random((n, 1, h, w)) < 0.2, np.round(motion), motion).astype(f32)
    previous = (2.0 * rng.random((n, c, h, w)) - 0.5).astype(f32)
    return [previous, prev_geometry, motion, normal, depth, np.array(10.0, f32), np.array(4.0, f32)]


SPEC = OpSpec(
    name="SvgfReproject",
    doc="previous warped along motion with SVGF's per-tap depth / normal tests (thresholds x "
    "(fwidth + 1e-2)), bilinear weights renormalised over the passing taps (valid where >= "
    "0.01), a 3 x 3 mean fallback around the rounded position (fallback=1), the mask eroded by a "
    "3 x 3 minimum (erode=1); outputs warped * mask and mask (Schied17 s.4.1, Choi24's history)",
    inputs=(*(Arg(name) for name in IMAGES), *(Arg(name, 0) for name in SCALARS)),
    outputs=(Arg("warped"), Arg("valid")),
    attrs=("fallback", "erode"),
    default_attrs={"fallback": 1, "erode": 1},
    example_attrs=({"fallback": 1, "erode": 1}, {"fallback": 0, "erode": 0}),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 9, 13, 17), (2, 3, 8, 6), (1, 1, 2, 5)),
)
