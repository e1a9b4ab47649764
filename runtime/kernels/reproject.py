"""Reproject as a fast kernel; spec: rtdenoise.ops.reproject.

`nearest` = 1: one offset per pixel of the row (the clamped position rounded), then a copy per
channel.

One output row per parallel iteration: the row's source positions, the flat offsets of their
four taps and the bilinear weights are computed once (clamped to the image, so every tap is in
bounds, whatever the motion), then every channel gathers its four taps per pixel. The float32
arithmetic is the torch form's, step by step and without fastmath (numba compiles the callees
with the caller's flags), so the forms agree to the bit rather than to ~1e-7: the temporal
state of some models (the bilateral grid's depth axis) amplifies such differences over frames.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, uintp

from .fast_kernel import fast_kernel


@njit(cache=True)
def _clamped(v, last):
    """v clamped to [0, last], written so that NaN lands on 0 (NaN compares false)."""
    if not v > np.float32(0.0):
        v = np.float32(0.0)
    if not v < last:
        v = last
    return v


@njit(cache=True)
def _source(motion_x, motion_y, x, y, h):
    """Pixel x of row y (of a w = len(motion_x) by h image): its previous position (px, py),
    float32, clamped to the image (the torch form's `clamped_position`)."""
    px = _clamped(np.float32(x) + motion_x[x], np.float32(motion_x.shape[0] - 1))
    py = _clamped(np.float32(y) + motion_y[x], np.float32(h - 1))
    return px, py


@njit(cache=True)
def _taps(motion_x, motion_y, y, h, taps, weights):
    """Per pixel x of the row: the clamped source position -> the flat offsets of its four
    bilinear taps, taps[k, x] (k: nw, ne, sw, se, into a plane of h * w), and their weights
    weights[k, x], in float32 as the torch form computes them."""
    w = motion_x.shape[0]
    one = np.float32(1.0)
    for x in range(w):
        px, py = _source(motion_x, motion_y, x, y, h)
        cx = int(px)  # floor: px >= 0
        cy = int(py)
        x1 = min(cx + 1, w - 1)
        y1 = min(cy + 1, h - 1)
        wx = px - np.float32(cx)
        wy = py - np.float32(cy)
        ex, ey = one - wx, one - wy
        taps[0, x], taps[1, x] = cy * w + cx, cy * w + x1
        taps[2, x], taps[3, x] = y1 * w + cx, y1 * w + x1
        weights[0, x], weights[1, x] = ey * ex, ey * wx
        weights[2, x], weights[3, x] = wy * ex, wy * wx


@njit(cache=True)
def _gather_row(plane, out, nw, ne, sw, se, w_nw, w_ne, w_sw, w_se):
    """out[x] = bilinear sample of the flat plane, the four corner terms in the torch form's
    order: nw (1 - wy)(1 - wx) + ne (1 - wy) wx + sw wy (1 - wx) + se wy wx. Unsigned
    indices: numba's wrap-around check on signed ones keeps the loop scalar."""
    for x in range(out.shape[0]):
        u = uintp(x)
        out[u] = (
            plane[uintp(nw[u])] * w_nw[u]
            + plane[uintp(ne[u])] * w_ne[u]
            + plane[uintp(sw[u])] * w_sw[u]
            + plane[uintp(se[u])] * w_se[u]
        )


@njit(cache=True)
def _nearest(motion_x, motion_y, y, h, index):
    """Per pixel x of the row: the flat offset index[x] (into a plane of h * w) of the pixel
    nearest to the clamped source position, floor(p + 0.5), in float32 as the torch form."""
    w = motion_x.shape[0]
    half = np.float32(0.5)
    for x in range(w):
        px, py = _source(motion_x, motion_y, x, y, h)
        index[x] = int(py + half) * w + int(px + half)  # floor: >= 0.5


@njit(parallel=True, cache=True)  # no fastmath: numba compiles the callees with these flags
def _reproject_nb(previous, motion, out, nearest):
    n_img, n_ch, h, w = previous.shape
    planes = previous.reshape(n_img, n_ch, h * w)
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        if nearest:  # one offset per pixel, then a copy per channel
            index = np.empty(w, np.int64)
            _nearest(motion[n, 0, y], motion[n, 1, y], y, h, index)
            for c in range(n_ch):
                plane, dst = planes[n, c], out[n, c, y]
                for x in range(w):
                    dst[uintp(x)] = plane[uintp(index[x])]
            continue
        taps = np.empty((4, w), np.int64)
        weights = np.empty((4, w), np.float32)
        _taps(motion[n, 0, y], motion[n, 1, y], y, h, taps, weights)
        for c in range(n_ch):
            _gather_row(
                planes[n, c],
                out[n, c, y],
                taps[0],
                taps[1],
                taps[2],
                taps[3],
                weights[0],
                weights[1],
                weights[2],
                weights[3],
            )


@fast_kernel("Reproject")
def reproject(previous: np.ndarray, motion: np.ndarray, out: np.ndarray, nearest: int = 0) -> None:
    """previous (N, C, H, W), motion (N, 2, H, W) -> out (N, C, H, W), bilinear or nearest."""
    _reproject_nb(previous, motion, out, bool(nearest))
