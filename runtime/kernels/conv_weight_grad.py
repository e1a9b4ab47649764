"""ConvWeightGrad as a fast kernel; spec: rtdenoise.ops.conv_weight_grad.

One parallel job per (output channel, kernel row): for every gradient row and input channel,
K dot products of the gradient row with the input row shifted by each kernel column (the
columns that fall outside the image skipped: the zero padding), each a float32 row sum
(fastmath: vectorised) added to a float64 total.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(parallel=True, cache=True, fastmath=True)
def _conv_weight_grad_nb(x, g, k, p, out):
    n_img, ci, h, w = x.shape
    co, ho, wo = g.shape[1], g.shape[2], g.shape[3]
    for job in prange(co * k):
        o = job // k
        ky = job - o * k
        acc = np.zeros((ci, k), np.float64)
        for n in range(n_img):
            for y in range(ho):
                sy = y + ky - p
                if sy < 0 or sy >= h:
                    continue
                grow = g[n, o, y]
                for i in range(ci):
                    xrow = x[n, i, sy]
                    for kx in range(k):
                        lo = max(0, p - kx)
                        hi = min(wo, w + p - kx)
                        s = np.float32(0.0)
                        for xo in range(lo, hi):
                            s += grow[xo] * xrow[xo + kx - p]
                        acc[i, kx] += s
        for i in range(ci):
            for kx in range(k):
                out[o, i, ky, kx] = np.float32(acc[i, kx])


@fast_kernel("ConvWeightGrad")
def conv_weight_grad(
    input: np.ndarray,
    grad_output: np.ndarray,
    grad_weight: np.ndarray,
    kernel_size: int = 3,
    padding: int = 1,
) -> None:
    """input (N, C_in, H, W), grad_output (N, C_out, H', W') -> grad_weight (C_out, C_in, K, K)."""
    _conv_weight_grad_nb(input, grad_output, kernel_size, padding, grad_weight)
