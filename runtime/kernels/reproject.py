"""Reproject as a fast kernel; spec: rtdenoise.ops.reproject.

One output row per parallel iteration: the row's source positions, taps and bilinear weights
are computed once (clamped to the image, so every tap is in bounds, whatever the motion), then
every channel gathers its four taps per pixel. The float32 arithmetic is the torch form's,
step by step and without fastmath (numba compiles the callees with the caller's flags), so
the forms agree to the bit rather than to ~1e-7: the temporal state of some models (the
bilateral grid's depth axis) amplifies such differences over frames.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(cache=True)
def _taps(motion_x, motion_y, y, h, x0, x1, y0, y1, wx, wy):
    """Per pixel of the row: the clamped source position -> taps (x0, x1, y0, y1) and weights
    (wx, wy), in float32 as the torch form computes them."""
    w = motion_x.shape[0]
    zero = np.float32(0.0)
    fw1, fh1 = np.float32(w - 1), np.float32(h - 1)
    for x in range(w):
        px = np.float32(x) + motion_x[x]
        py = np.float32(y) + motion_y[x]
        # clamped to the image; written so that NaN lands in it too (NaN compares false)
        if not px > zero:
            px = zero
        if not px < fw1:
            px = fw1
        if not py > zero:
            py = zero
        if not py < fh1:
            py = fh1
        cx = int(px)  # floor: px >= 0
        cy = int(py)
        x0[x] = cx
        y0[x] = cy
        x1[x] = min(cx + 1, w - 1)
        y1[x] = min(cy + 1, h - 1)
        wx[x] = px - np.float32(cx)
        wy[x] = py - np.float32(cy)


@njit(cache=True)
def _gather_row(src, out, x0, x1, y0, y1, wx, wy):
    """out[x] = bilinear sample of the plane src, the four corner terms in the torch form's
    order: nw (1 - wy)(1 - wx) + ne (1 - wy) wx + sw wy (1 - wx) + se wy wx."""
    one = np.float32(1.0)
    for x in range(out.shape[0]):
        ex, ey = one - wx[x], one - wy[x]
        out[x] = (
            src[y0[x], x0[x]] * (ey * ex)
            + src[y0[x], x1[x]] * (ey * wx[x])
            + src[y1[x], x0[x]] * (wy[x] * ex)
            + src[y1[x], x1[x]] * (wy[x] * wx[x])
        )


@njit(parallel=True, cache=True)  # no fastmath: numba compiles the callees with these flags
def _reproject_nb(previous, motion, out):
    n_img, n_ch, h, w = previous.shape
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        x0 = np.empty(w, np.int64)
        x1 = np.empty(w, np.int64)
        y0 = np.empty(w, np.int64)
        y1 = np.empty(w, np.int64)
        wx = np.empty(w, np.float32)
        wy = np.empty(w, np.float32)
        _taps(motion[n, 0, y], motion[n, 1, y], y, h, x0, x1, y0, y1, wx, wy)
        for c in range(n_ch):
            _gather_row(previous[n, c], out[n, c, y], x0, x1, y0, y1, wx, wy)


@fast_kernel("Reproject")
def reproject(previous: np.ndarray, motion: np.ndarray, out: np.ndarray) -> None:
    """previous (N, C, H, W), motion (N, 2, H, W) -> out (N, C, H, W)."""
    _reproject_nb(previous, motion, out)
