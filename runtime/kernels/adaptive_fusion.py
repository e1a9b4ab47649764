"""AdaptiveFusion as a fast kernel (Lee24 eq. (3)); defined in rtdenoise.ops.adaptive_fusion.

out = d_ta + alpha * U(d_low - D(d_ta)), D = 2 x 2 mean, U = nearest x2; H and W even.
One low-resolution row (two output rows) per parallel iteration.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(cache=True, fastmath=True)
def _diff_row(low, top, bottom, diff):
    """diff[X] = low[X] - mean of the 2 x 2 block of (top, bottom) at column 2X."""
    for x in range(diff.shape[0]):
        pooled = (top[2 * x] + top[2 * x + 1] + bottom[2 * x] + bottom[2 * x + 1]) * 0.25
        diff[x] = low[x] - pooled


@njit(cache=True, fastmath=True)
def _fuse_row(ta, alpha, diff, out):
    """out[x] = ta[x] + alpha[x] * diff[x // 2]."""
    for x in range(out.shape[0]):
        out[x] = ta[x] + alpha[x] * diff[x >> 1]


@njit(parallel=True, cache=True, fastmath=True)
def _adaptive_fusion_nb(d_ta, d_low, alpha, out):
    n_img, n_ch, h, w = d_ta.shape
    h2 = h // 2
    for row in prange(n_img * n_ch * h2):
        n = row // (n_ch * h2)
        rem = row - n * n_ch * h2
        c = rem // h2
        yl = rem - c * h2
        diff = np.empty(w // 2, dtype=np.float32)
        _diff_row(d_low[n, c, yl], d_ta[n, c, 2 * yl], d_ta[n, c, 2 * yl + 1], diff)
        for y in (2 * yl, 2 * yl + 1):
            _fuse_row(d_ta[n, c, y], alpha[n, 0, y], diff, out[n, c, y])


@fast_kernel("AdaptiveFusion")
def adaptive_fusion(
    d_ta: np.ndarray, d_low: np.ndarray, alpha: np.ndarray, out: np.ndarray
) -> None:
    """d_ta (N, C, H, W), d_low (N, C, H/2, W/2), alpha (N, 1, H, W) -> out (N, C, H, W)."""
    _adaptive_fusion_nb(d_ta, d_low, alpha, out)
