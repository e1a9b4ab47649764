"""TemporalAccumulation: one step of the accumulating families' temporal accumulation (TA).

    warped = Reproject([ta_state, geometry_state], motion)      (rtdenoise.ops.reproject)
    history, history_len, prev_normal, prev_depth = the channels of warped
    valid = in_bounds(motion) & |prev_depth - depth| < depth_tolerance |depth|
            & <prev_normal, normal> > normal_threshold, and reset == 0
    n = history_len where valid else 0;   h = history where valid else 0
    alpha = max(1 / (n + 1), min_alpha)               (Lee24 III-A after Meng20, Fan21, BMFR)
    accumulated = alpha current + (1 - alpha) h;      blend = alpha
    next_ta = [accumulated, min(n + 1, max_history)];  next_geometry = [normal, depth]

in_bounds: the previous position (x + mx, y + my) lies within [-0.5, W - 0.5] x [-0.5, H - 0.5].
An invalid history is dropped by selection, never multiplied by 0, so a non-finite history
cannot leak into the output. The whole step as one op: in ONNX Runtime the same arithmetic in
standard ops took about 40 small nodes (concatenations, slices, comparisons, Where) per frame.
`rtdenoise.models.temporal` documents the scheme; its functions are the torch form.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, same_nhw

IMAGES = ("current", "motion", "depth", "normal", "ta_state", "geometry_state")
SCALARS = ("reset", "depth_tolerance", "normal_threshold", "min_alpha", "max_history")


def _check(shapes, attrs) -> None:
    same_nhw("TemporalAccumulation", shapes[: len(IMAGES)], IMAGES)
    c = shapes[0][1]
    expected = {"motion": 2, "depth": 1, "normal": 3, "ta_state": c + 1, "geometry_state": 4}
    for name, shape in zip(IMAGES[1:], shapes[1 : len(IMAGES)], strict=True):
        if shape[1] != expected[name]:
            raise ValueError(
                f"TemporalAccumulation: {name} has {shape[1]} channels; expected "
                f"{expected[name]} (current has {c})"
            )


def _output_shapes(shapes, attrs) -> list:
    n, c, h, w = shapes[0]
    return [(n, c, h, w), (n, 1, h, w), (n, c + 1, h, w), (n, 4, h, w)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """A frame and a history that agree on most pixels: motion mostly within 2 px (some far
    off-screen), smooth depth in [1, 2) and normals; the previous geometry equal to them except
    on a quarter of the pixels (other normal, depth 3); history lengths 0..80 (some beyond
    max_history); reset 0."""
    n, c, h, w = shape
    f32 = np.float32
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    phase = rng.uniform(0, 2 * np.pi, (n, 1, 1, 1))
    depth = (1.5 + 0.4 * np.sin(xs / 5.0 + ys / 7.0 + phase)).astype(f32)
    tilt = 0.2 * np.sin(xs / 6.0 - ys / 4.0 + phase)
    normal = np.concatenate([tilt, 0.5 * tilt, np.ones_like(tilt)], axis=1)
    normal = (normal / np.linalg.norm(normal, axis=1, keepdims=True)).astype(f32)
    agree = rng.random((n, 1, h, w)) < 0.75
    prev_normal = np.where(agree, normal, normal[:, ::-1])
    prev_depth = np.where(agree, depth, 3.0)
    current = (2.0 * rng.random((n, c, h, w))).astype(f32)
    motion = rng.uniform(-2.0, 2.0, (n, 2, h, w))
    motion = np.where(rng.random((n, 1, h, w)) < 0.1, 10.0 * motion, motion).astype(f32)
    history = (2.0 * rng.random((n, c, h, w))).astype(f32)
    history_len = rng.integers(0, 81, (n, 1, h, w)).astype(f32)
    scalars = [0.0, 0.1, 0.9, 0.2, 64.0]  # reset, depth / normal tests, min_alpha, max_history
    return [
        current,
        motion,
        depth,
        normal,
        np.concatenate([history, history_len], axis=1),
        np.concatenate([prev_normal, prev_depth], axis=1).astype(f32),
        *(np.array(s, f32) for s in scalars),
    ]


SPEC = OpSpec(
    name="TemporalAccumulation",
    doc="accumulated = a current + (1 - a) history (a = max(1 / (n + 1), min_alpha), n the "
    "history length) where the history Reproject-ed by motion is in bounds and agrees in depth "
    "and normal, else current; outputs accumulated, a, next TA state, next geometry",
    inputs=(*(Arg(name) for name in IMAGES), *(Arg(name, 0) for name in SCALARS)),
    outputs=(Arg("accumulated"), Arg("blend"), Arg("next_ta"), Arg("next_geometry")),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 1, 5)),
)
