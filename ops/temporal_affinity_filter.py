"""TemporalAffinityFilter: the last spatial kernel and the temporal kernel, normalised jointly
(Isik21 eq. (7)-(8)).

out_p = (c_p x_p + sum_{q != p} w_pq x_q + sum_{q'} v_q' omega_pq' prev_q')
        / (1e-10 + c_p + sum_{q != p} w_pq + sum_{q'} v_q' omega_pq')
w_pq = exp(-a_p ||f_p - f_q||^2)            (eq. (4): k x k taps at the dilation)
omega_pq' = exp(-b_p ||f_p - g_q'||^2)       (eq. (7): kt x kt taps at dilation 1, no centre
                                              weight)

image x (N, C, H, W) = L^(K-1); features f (N, D, H, W) = f^K; bandwidth a, centre c
(N, 1, H, W); previous (N, C, H, W) = the warped previous output W O_{t-1}; previous_features
g (N, D, H, W) = the warped W f^K_{t-1}; temporal_bandwidth b >= 0 (N, 1, H, W); valid v
(N, 1, H, W) in [0, 1]: where the warped previous frame may be used (0 everywhere on the
first frame: Isik21 "omega = 0 at t = 0"). Taps outside the image have weight 0. k and kt are
float32 scalar inputs (odd integers), like AffinityFilter's; the dilation is an attribute.
"""

from __future__ import annotations

import numpy as np

from .affinity_filter import EXAMPLE_KERNEL_SIZE, check_guides, example_guides
from .spec import Arg, OpSpec, same_nhw

INPUTS = (
    "image",
    "features",
    "bandwidth",
    "centre",
    "previous",
    "previous_features",
    "temporal_bandwidth",
    "valid",
    "kernel_size",
    "temporal_size",
)


def _check(shapes, attrs) -> None:
    op = "TemporalAffinityFilter"
    if attrs["dilation"] < 1:
        raise ValueError(f"{op} needs dilation >= 1, got {attrs['dilation']}")
    check_guides(op, shapes[:4], INPUTS[:4])
    check_guides(op, [shapes[4], shapes[5], shapes[6], shapes[7]], INPUTS[4:8])
    same_nhw(op, [shapes[0], shapes[4]], ("image", "previous"))
    if tuple(shapes[4]) != tuple(shapes[0]) or tuple(shapes[5]) != tuple(shapes[1]):
        raise ValueError(
            f"{op}: previous {tuple(shapes[4])} and previous_features {tuple(shapes[5])} must "
            f"have the shapes of image {tuple(shapes[0])} and features {tuple(shapes[1])}"
        )


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """AffinityFilter's example inputs plus a previous output and features (the current ones
    perturbed), a temporal bandwidth in [0, 0.4), a random 0/1 validity, k = kt = 13."""
    n, _, h, w = shape
    image = (4.0 * rng.random(shape, dtype=np.float32)).astype(np.float32)
    features, bandwidth, centre = example_guides(n, h, w, rng)
    previous = (4.0 * rng.random(shape, dtype=np.float32)).astype(np.float32)
    noise = 0.5 * rng.standard_normal(features.shape, dtype=np.float32)
    previous_features = (features + noise).astype(np.float32)
    temporal_bandwidth = (0.4 * rng.random((n, 1, h, w), dtype=np.float32)).astype(np.float32)
    valid = (rng.random((n, 1, h, w)) < 0.8).astype(np.float32)
    size = np.array(EXAMPLE_KERNEL_SIZE, np.float32)
    return [
        image,
        features,
        bandwidth,
        centre,
        previous,
        previous_features,
        temporal_bandwidth,
        valid,
        size,
        size.copy(),
    ]


SPEC = OpSpec(
    name="TemporalAffinityFilter",
    doc="out_p = (c_p x_p + sum_{q != p} w_pq x_q + sum_q' v_q' omega_pq' prev_q') / (1e-10 + "
    "c_p + sum_{q != p} w_pq + sum_q' v_q' omega_pq'), w_pq = exp(-a_p ||f_p - f_q||^2) over k x "
    "k taps at the dilation, omega_pq' = exp(-b_p ||f_p - g_q'||^2) over kt x kt taps at "
    "dilation 1, taps inside the image (Isik21 eq. 7-8)",
    inputs=tuple(Arg(name, 0 if name.endswith("size") else 4) for name in INPUTS),
    outputs=(Arg("output"),),
    attrs=("dilation",),
    output_shapes=lambda shapes, attrs: [tuple(shapes[0])],
    check=_check,
    example_inputs=_example_inputs,
    default_attrs={"dilation": 4},
    example_attrs=({"dilation": 1}, {"dilation": 4}),
    example_shapes=((1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 30, 41)),
)
