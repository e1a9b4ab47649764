"""Reproject as a fast kernel; spec: rtdenoise.ops.reproject.

One output row per parallel iteration: the row's source positions, taps and bilinear weights
are computed once (clamped to the image, so every tap is in bounds, whatever the motion), then
every channel gathers its four taps per pixel.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(cache=True, fastmath=True)
def _taps(motion_x, motion_y, y, h, x0, x1, y0, y1, fx, fy):
    """Per pixel of the row: clamped source position -> taps (x0, x1, y0, y1), weights fx, fy."""
    w = motion_x.shape[0]
    for x in range(w):
        px = x + motion_x[x]
        py = y + motion_y[x]
        # written so that NaN lands in the image too (every comparison with NaN is false)
        if not px > 0.0:
            px = 0.0
        if not px < w - 1:
            px = np.float32(w - 1)
        if not py > 0.0:
            py = 0.0
        if not py < h - 1:
            py = np.float32(h - 1)
        ix = int(px)
        iy = int(py)
        x0[x] = ix
        y0[x] = iy
        x1[x] = min(ix + 1, w - 1)
        y1[x] = min(iy + 1, h - 1)
        fx[x] = px - ix
        fy[x] = py - iy


@njit(cache=True, fastmath=True)
def _gather_row(src, out, x0, x1, y0, y1, fx, fy):
    """out[x] = bilinear sample of the plane src at the row's taps."""
    for x in range(out.shape[0]):
        a = src[y0[x], x0[x]] + fx[x] * (src[y0[x], x1[x]] - src[y0[x], x0[x]])
        b = src[y1[x], x0[x]] + fx[x] * (src[y1[x], x1[x]] - src[y1[x], x0[x]])
        out[x] = a + fy[x] * (b - a)


@njit(parallel=True, cache=True, fastmath=True)
def _reproject_nb(previous, motion, out):
    n_img, n_ch, h, w = previous.shape
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        x0 = np.empty(w, np.int64)
        x1 = np.empty(w, np.int64)
        y0 = np.empty(w, np.int64)
        y1 = np.empty(w, np.int64)
        fx = np.empty(w, np.float32)
        fy = np.empty(w, np.float32)
        _taps(motion[n, 0, y], motion[n, 1, y], y, h, x0, x1, y0, y1, fx, fy)
        for c in range(n_ch):
            _gather_row(previous[n, c], out[n, c, y], x0, x1, y0, y1, fx, fy)


@fast_kernel("Reproject")
def reproject(previous: np.ndarray, motion: np.ndarray, out: np.ndarray) -> None:
    """previous (N, C, H, W), motion (N, 2, H, W) -> out (N, C, H, W)."""
    _reproject_nb(previous, motion, out)
