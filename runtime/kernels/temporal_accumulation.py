"""TemporalAccumulation as a fast kernel; spec: rtdenoise.ops.temporal_accumulation.

One output row per parallel iteration: Reproject's taps and weights for the row
(`reproject._taps`), the C + 5 warped state rows gathered into a row buffer
(`reproject._gather_row`), then per pixel the validity test and the blend, writing the four
outputs. The float32 arithmetic is the torch form's, step by step and without fastmath, so the
forms agree to the bit: a history-validity decision that flipped between forms would change a
pixel's whole history.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel
from .reproject import _gather_row, _taps


@njit(parallel=True, cache=True)  # no fastmath (see the module docstring)
def _temporal_accumulation_nb(
    current, motion, depth, normal, ta_state, geometry_state, keep, tolerance, threshold,
    min_alpha, max_history, accumulated, blend, next_ta, next_geometry,
):  # fmt: skip
    n_img, n_ch, h, w = current.shape
    ta_planes = ta_state.reshape(n_img, n_ch + 1, h * w)
    geo_planes = geometry_state.reshape(n_img, 4, h * w)
    zero, one, half = np.float32(0.0), np.float32(1.0), np.float32(0.5)
    lo, hi_x, hi_y = np.float32(-0.5), np.float32(w) - half, np.float32(h) - half
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        taps = np.empty((4, w), np.int64)
        weights = np.empty((4, w), np.float32)
        warped = np.empty((n_ch + 5, w), np.float32)
        mx, my = motion[n, 0, y], motion[n, 1, y]
        _taps(mx, my, y, h, taps, weights)
        t0, t1, t2, t3 = taps[0], taps[1], taps[2], taps[3]
        w0, w1, w2, w3 = weights[0], weights[1], weights[2], weights[3]
        for c in range(n_ch + 1):
            _gather_row(ta_planes[n, c], warped[c], t0, t1, t2, t3, w0, w1, w2, w3)
        for c in range(4):
            _gather_row(geo_planes[n, c], warped[n_ch + 1 + c], t0, t1, t2, t3, w0, w1, w2, w3)
        d_row, y_f = depth[n, 0, y], np.float32(y)
        for x in range(w):
            px = np.float32(x) + mx[x]
            py = y_f + my[x]
            inside = px >= lo and px <= hi_x and py >= lo and py <= hi_y
            d = d_row[x]
            depth_ok = abs(warped[n_ch + 4, x] - d) < tolerance * abs(d)
            dot = warped[n_ch + 1, x] * normal[n, 0, y, x]
            dot += warped[n_ch + 2, x] * normal[n, 1, y, x]
            dot += warped[n_ch + 3, x] * normal[n, 2, y, x]
            valid = one if inside and depth_ok and dot > threshold else zero
            ok = valid * keep > half
            n_prev = warped[n_ch, x] if ok else zero
            n_next = n_prev + one
            alpha = max(one / n_next, min_alpha)
            rest = one - alpha
            for c in range(n_ch):
                hist = warped[c, x] if ok else zero
                acc = alpha * current[n, c, y, x] + rest * hist
                accumulated[n, c, y, x] = acc
                next_ta[n, c, y, x] = acc
            blend[n, 0, y, x] = alpha
            next_ta[n, n_ch, y, x] = min(n_next, max_history)
            for c in range(3):
                next_geometry[n, c, y, x] = normal[n, c, y, x]
            next_geometry[n, 3, y, x] = d


@fast_kernel("TemporalAccumulation")
def temporal_accumulation(
    current: np.ndarray,
    motion: np.ndarray,
    depth: np.ndarray,
    normal: np.ndarray,
    ta_state: np.ndarray,
    geometry_state: np.ndarray,
    reset: np.ndarray,
    depth_tolerance: np.ndarray,
    normal_threshold: np.ndarray,
    min_alpha: np.ndarray,
    max_history: np.ndarray,
    accumulated: np.ndarray,
    blend: np.ndarray,
    next_ta: np.ndarray,
    next_geometry: np.ndarray,
) -> None:
    """current (N, C, H, W), motion, depth, normal, ta_state (N, C + 1, H, W), geometry_state
    (N, 4, H, W) and five scalars -> accumulated, blend, next_ta, next_geometry."""
    f32 = np.float32
    _temporal_accumulation_nb(
        current, motion, depth, normal, ta_state, geometry_state,
        f32(1.0) - f32(reset), f32(depth_tolerance), f32(normal_threshold), f32(min_alpha),
        f32(max_history), accumulated, blend, next_ta, next_geometry,
    )  # fmt: skip
