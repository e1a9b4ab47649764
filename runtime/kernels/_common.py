"""numba row helpers shared by the kernels (no torch: runtime/ must run without it)."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, fastmath=True)
def add_into(dst, a):
    """dst += a, element-wise over a contiguous float32 row (vectorises)."""
    for x in range(dst.shape[0]):
        dst[x] += a[x]


# 2^f = exp(f ln 2) on [-1/2, 1/2]: Taylor to degree 6, relative error < 2e-7
_P = (1.0, 0.6931472, 0.2402265, 0.05550411, 0.009618129, 0.001333355, 0.0001540353)


@njit(cache=True, fastmath=True)
def exp_row(dst, arg):
    """dst = exp(arg) for arg <= 0 over a contiguous float32 row, in a loop LLVM vectorises
    (numba has no vector libm here): 2^k (k = round(arg log2 e)) from the exponent bits, 2^f
    from a polynomial. Arguments below -87 give ~1e-38 instead of 0 (negligible as weights)."""
    bits = dst.view(np.int32)
    for x in range(dst.shape[0]):
        t = max(arg[x] * np.float32(1.442695), np.float32(-126.0))
        k = np.floor(t + np.float32(0.5))
        f = t - k
        p = np.float32(_P[6])
        p = p * f + np.float32(_P[5])
        p = p * f + np.float32(_P[4])
        p = p * f + np.float32(_P[3])
        p = p * f + np.float32(_P[2])
        p = p * f + np.float32(_P[1])
        p = p * f + np.float32(_P[0])
        bits[x] = (np.int32(k) + np.int32(127)) << np.int32(23)
        dst[x] = dst[x] * p
