"""TemporalAccumulation as a fast kernel; spec: rtdenoise.ops.temporal_accumulation.

One output row per parallel iteration: Reproject's taps and weights for the row
(`reproject._taps`), the C + 5 warped state rows gathered into a row buffer
(`reproject._gather_row`), then the validity test, n and alpha per pixel, and the blend one
channel row at a time (branch-free row loops with unsigned indices, which LLVM vectorises:
0.73x the time of one per-pixel loop over everything at 720p, the same bits).

per_tap = 1 (`_temporal_accumulation_per_tap_nb`, models.temporal.per_tap_history): one
pixel at a time, its four taps tested and their weights and states summed in the torch form's
tap order (nw, ne, sw, se; a rejected tap adds nothing, as its selected-away 0 does there),
then the renormalisation, n, alpha and the blend. per_tap = 2 is the same kernel with `hdr`:
each accepted tap's averaging weight is divided by 1 + its brightness above the bound
HDR_RATIO x the darkest accepted tap's + HDR_FLOOR (brightness: the channel mean of its
accumulated values, summed in channel order, at least 0; models.temporal.tap_brightness and
outlier_bound), the 0.01 cut still on the plain weights.

The float32 arithmetic is the torch form's, step by step and without fastmath, so the forms
agree to the bit: a history-validity decision that flipped between forms would change a
pixel's whole history.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, uintp

from rtdenoise.ops.temporal_accumulation import HDR_FLOOR, HDR_RATIO

from .fast_kernel import fast_kernel
from .reproject import _gather_row, _taps


@njit(cache=True)
def _blend_row(current, history, ok, alpha, accumulated, next_ta):
    """accumulated[x] = next_ta[x] = alpha current + (1 - alpha) (history where ok, else 0)."""
    zero, one = np.float32(0.0), np.float32(1.0)
    for x in range(current.shape[0]):
        u = uintp(x)
        a = alpha[u]
        kept = history[u] if ok[u] else zero
        value = a * current[u] + (one - a) * kept
        accumulated[u] = value
        next_ta[u] = value


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
        ok = np.empty(w, np.bool_)
        mx, my = motion[n, 0, y], motion[n, 1, y]
        _taps(mx, my, y, h, taps, weights)
        t0, t1, t2, t3 = taps[0], taps[1], taps[2], taps[3]
        w0, w1, w2, w3 = weights[0], weights[1], weights[2], weights[3]
        for c in range(n_ch + 1):
            _gather_row(ta_planes[n, c], warped[c], t0, t1, t2, t3, w0, w1, w2, w3)
        for c in range(4):
            _gather_row(geo_planes[n, c], warped[n_ch + 1 + c], t0, t1, t2, t3, w0, w1, w2, w3)
        # per pixel: validity (models.temporal.history_validity), n and alpha (accumulate)
        d_row, y_f = depth[n, 0, y], np.float32(y)
        nx, ny, nz = normal[n, 0, y], normal[n, 1, y], normal[n, 2, y]
        count, pnx, pny, pnz = warped[n_ch], warped[n_ch + 1], warped[n_ch + 2], warped[n_ch + 3]
        prev_depth, alpha, new_len = warped[n_ch + 4], blend[n, 0, y], next_ta[n, n_ch, y]
        for x in range(w):
            u = uintp(x)
            px = np.float32(x) + mx[u]
            py = y_f + my[u]
            inside = (px >= lo) & (px <= hi_x) & (py >= lo) & (py <= hi_y)
            d = d_row[u]
            depth_ok = abs(prev_depth[u] - d) < tolerance * abs(d)
            dot = pnx[u] * nx[u]
            dot += pny[u] * ny[u]
            dot += pnz[u] * nz[u]
            valid = one if inside & depth_ok & (dot > threshold) else zero
            kept = valid * keep > half
            ok[u] = kept
            n_next = (count[u] if kept else zero) + one
            alpha[u] = max(one / n_next, min_alpha)
            new_len[u] = min(n_next, max_history)
        for c in range(n_ch):  # the blend, one channel row at a time
            _blend_row(
                current[n, c, y], warped[c], ok, alpha, accumulated[n, c, y], next_ta[n, c, y]
            )
        for c in range(3):
            next_geometry[n, c, y, :] = normal[n, c, y, :]
        next_geometry[n, 3, y, :] = d_row


@njit(parallel=True, cache=True)  # no fastmath (see the module docstring)
def _temporal_accumulation_per_tap_nb(
    current, motion, depth, normal, ta_state, geometry_state, keep, tolerance, threshold,
    min_alpha, max_history, accumulated, blend, next_ta, next_geometry, hdr,
):  # fmt: skip
    n_img, n_ch, h, w = current.shape
    ta_planes = ta_state.reshape(n_img, n_ch + 1, h * w)
    geo_planes = geometry_state.reshape(n_img, 4, h * w)
    zero, one, half, cut = np.float32(0.0), np.float32(1.0), np.float32(0.5), np.float32(0.01)
    x_max, y_max = np.float32(w - 1), np.float32(h - 1)
    ratio, floor = np.float32(HDR_RATIO), np.float32(HDR_FLOOR)
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        y_f = np.float32(y)
        acc = np.empty(n_ch + 1, np.float32)
        index = np.empty(4, np.int64)
        weights = np.empty(4, np.float32)
        bright = np.empty(4, np.float32)
        bound = np.float32(0.0)
        for x in range(w):
            px = np.float32(x) + motion[n, 0, y, x]
            py = y_f + motion[n, 1, y, x]
            x0 = np.float32(np.floor(px))
            y0 = np.float32(np.floor(py))
            ax = px - x0
            ay = py - y0
            ex = one - ax
            ey = one - ay
            d = depth[n, 0, y, x]
            tol = tolerance * abs(d)
            nx, ny, nz = normal[n, 0, y, x], normal[n, 1, y, x], normal[n, 2, y, x]
            count = 0  # the accepted taps, in tap order
            for t in range(4):  # nw, ne, sw, se
                right, down = t & 1, t >> 1
                fx = x0 + one if right else x0
                fy = y0 + one if down else y0
                weight = (ax if right else ex) * (ay if down else ey)
                if not ((fx >= zero) & (fx <= x_max) & (fy >= zero) & (fy <= y_max)):
                    continue
                i = int(fy) * w + int(fx)
                if not (abs(geo_planes[n, 3, i] - d) < tol):
                    continue
                dot = geo_planes[n, 0, i] * nx
                dot += geo_planes[n, 1, i] * ny
                dot += geo_planes[n, 2, i] * nz
                if not (dot > threshold):
                    continue
                index[count] = i
                weights[count] = weight
                count += 1
            if hdr:  # models.temporal.outlier_bound, then each tap's weight over its excess
                darkest = np.float32(np.inf)
                for k in range(count):
                    b = ta_planes[n, 0, index[k]]
                    for c in range(1, n_ch):
                        b = b + ta_planes[n, c, index[k]]
                    b = b / np.float32(n_ch)
                    b = zero if b < zero else b  # NaN stays NaN, as torch's clamp
                    bright[k] = b
                    darkest = b if b < darkest else darkest
                bound = ratio * darkest + floor
            acc[:] = zero
            total = zero  # the accepted taps' bilinear weight (the cut)
            weighed = zero  # their averaging weight (= total unless hdr)
            for k in range(count):
                i, weight = index[k], weights[k]
                average_weight = weight
                if hdr:
                    excess = bright[k] - bound
                    excess = zero if excess < zero else excess
                    scale = one + excess
                    if hdr == 2:  # per_tap 3: the square, a product as in the torch form
                        scale = scale * scale
                    average_weight = weight / scale
                for c in range(n_ch + 1):
                    acc[c] = acc[c] + average_weight * ta_planes[n, c, i]
                total = total + weight
                weighed = weighed + average_weight
            valid = one if total >= cut else zero
            kept = valid * keep > half
            n_prev = acc[n_ch] / weighed if kept else zero
            n_next = n_prev + one
            a = max(one / n_next, min_alpha)
            blend[n, 0, y, x] = a
            next_ta[n, n_ch, y, x] = min(n_next, max_history)
            for c in range(n_ch):
                kept_c = acc[c] / weighed if kept else zero
                value = a * current[n, c, y, x] + (one - a) * kept_c
                accumulated[n, c, y, x] = value
                next_ta[n, c, y, x] = value
        for c in range(3):
            next_geometry[n, c, y, :] = normal[n, c, y, :]
        next_geometry[n, 3, y, :] = depth[n, 0, y, :]


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
    per_tap: int = 0,
) -> None:
    """current (N, C, H, W), motion, depth, normal, ta_state (N, C + 1, H, W), geometry_state
    (N, 4, H, W) and five scalars -> accumulated, blend, next_ta, next_geometry; per_tap picks
    the reprojection (0 bilinear, 1 per tap, 2 per tap HDR-weighted, 3 by the square)."""
    f32 = np.float32
    args = (
        current, motion, depth, normal, ta_state, geometry_state,
        f32(1.0) - f32(reset), f32(depth_tolerance), f32(normal_threshold), f32(min_alpha),
        f32(max_history), accumulated, blend, next_ta, next_geometry,
    )  # fmt: skip
    if per_tap:
        _temporal_accumulation_per_tap_nb(*args, max(per_tap - 1, 0))
    else:
        _temporal_accumulation_nb(*args)
