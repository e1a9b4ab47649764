"""TemporalAccumulation: one step of the accumulating families' temporal accumulation (TA).

Attribute per_tap selects how the previous state is reprojected and tested (optional on a node:
an omitted one is 0, so models exported before it existed run as before).

per_tap = 0 (bilinear; the models exported before the attribute): the whole state is warped,
then the *interpolated* previous depth and normal are tested once per pixel:

    warped = Reproject([ta_state, geometry_state], motion)      (rtdenoise.ops.reproject)
    history, history_len, prev_normal, prev_depth = the channels of warped
    valid = in_bounds(motion) & |prev_depth - depth| < depth_tolerance |depth|
            & <prev_normal, normal> > normal_threshold, and reset == 0

per_tap = 1 (SVGF, Schied17 s.4.1; BMFR): each of the four bilinear taps around the previous
position p = (x + mx, y + my) is tested on its own against the current pixel and the bilinear
weights are renormalised over the accepted taps:

    taps t = (x0 + i, y0 + j), i, j in {0, 1}, (x0, y0) = floor(p), a = p - (x0, y0),
    w_t = (1 - a_x)(1 - a_y), a_x (1 - a_y), (1 - a_x) a_y, a_x a_y   (nw, ne, sw, se)
    ok_t = t inside [0, W - 1] x [0, H - 1] & |depth_prev[t] - depth| < depth_tolerance |depth|
           & <normal_prev[t], normal> > normal_threshold
    total = sum w_t over ok_t;   [history, history_len] = sum_{ok_t} w_t ta_state[t] / total
    valid = total >= 0.01 (the accepted taps' weight, as in SVGF; 0 when no tap passes),
            and reset == 0

(no separate in-bounds test: a position within a pixel of the border keeps its inside taps;
the taps' values are never interpolated across a rejected tap, so a silhouette's background
taps stay out of a foreground pixel's history).

per_tap = 2 (per tap, HDR-weighted; after Karis14's 1 / (1 + luma) weights of TAA's resolve):
the taps and tests of per_tap = 1, and in the average each accepted tap's weight is divided by
1 + its brightness above a bound set by the darkest accepted tap, so that a bright tap (a small
light, a highlight) does not bleed into a dark neighbour through the bilinear blend frame after
frame, while taps within the bound (noise, texture) average as for per_tap = 1:

    l_t = max((ta_state[t][0] + ... + ta_state[t][C - 1]) / C, 0)    (summed in channel order)
    bound = HDR_RATIO min_{ok_t} l_t + HDR_FLOOR     (4 and 1; the minimum folded in tap order
                                                      from +inf by l_t < darkest)
    v_t = w_t / (1 + max(l_t - bound, 0))
    [history, history_len] = sum_{ok_t} v_t ta_state[t] / sum_{ok_t} v_t
    valid = total >= 0.01 as for per_tap = 1 (the plain w_t: the same pixels keep history)

per_tap = 3 (per tap, HDR-weighted, squared): per_tap = 2 with v_t = w_t / (1 + max(l_t -
bound, 0))^2 (the square a product, not a power). Under 2 an outlier tap's share of the sum,
v_t l_t, tends to w_t as l_t grows: a light's tap still puts up to about one unit into its dark
neighbour at every sub-pixel warp, and that accumulates over the frames; under 3 it falls as
1 / l_t.

The brightness is read in the units the values come in (demodulated radiance for the
accumulating families, where 1 is a white surface under unit light). Then, for every per_tap:

    n = history_len where valid else 0;   h = history where valid else 0
    alpha = max(1 / (n + 1), min_alpha)               (Lee24 III-A after Meng20, Fan21, BMFR)
    accumulated = alpha current + (1 - alpha) h;      blend = alpha
    next_ta = [accumulated, min(n + 1, max_history)];  next_geometry = [normal, depth]

in_bounds: the previous position (x + mx, y + my) lies within [-0.5, W - 0.5] x [-0.5, H - 0.5].
An invalid history (or tap) is dropped by selection, never multiplied by 0, so a non-finite
history cannot leak into the output. The whole step as one op: in ONNX Runtime the same
arithmetic in standard ops took about 40 small nodes (concatenations, slices, comparisons,
Where) per frame. `rtdenoise.models.temporal` documents the scheme; its functions are the
torch form.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec, example_geometry, same_nhw

IMAGES = ("current", "motion", "depth", "normal", "ta_state", "geometry_state")
SCALARS = ("reset", "depth_tolerance", "normal_threshold", "min_alpha", "max_history")
PER_TAP = (0, 1, 2, 3)  # bilinear, per tap, per tap HDR-weighted (plain, squared)
HDR_RATIO = 4.0  # per_tap 2, 3: a tap brighter than HDR_RATIO x the darkest accepted one
HDR_FLOOR = 1.0  # + HDR_FLOOR (a white surface under unit light) is an outlier


def _check(shapes, attrs) -> None:
    if attrs["per_tap"] not in PER_TAP:
        raise ValueError(
            f"TemporalAccumulation: per_tap is {attrs['per_tap']}; expected 0, 1, 2 or 3"
        )
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
    depth, normal, agree = example_geometry(shape, rng)
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
    "and normal (per_tap=1: each bilinear tap tested, weights renormalised over the accepted "
    "ones, SVGF; per_tap=2: each tap's weight divided by 1 + its brightness above 4x the "
    "darkest tap's + 1; per_tap=3: by its square), else current; outputs accumulated, a, "
    "next TA state, next geometry",
    inputs=(*(Arg(name) for name in IMAGES), *(Arg(name, 0) for name in SCALARS)),
    outputs=(Arg("accumulated"), Arg("blend"), Arg("next_ta"), Arg("next_geometry")),
    attrs=("per_tap",),
    default_attrs={"per_tap": 0},
    example_attrs=({"per_tap": 0}, {"per_tap": 1}, {"per_tap": 2}, {"per_tap": 3}),
    optional_attrs={"per_tap": 0},  # models exported before per_tap existed
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 1, 5)),
)
