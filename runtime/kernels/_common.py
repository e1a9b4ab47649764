"""numba row helpers shared by the kernels (no torch: runtime/ must run without it)."""

from __future__ import annotations

from numba import njit


@njit(cache=True, fastmath=True)
def add_into(dst, a):
    """dst += a, element-wise over a contiguous float32 row (vectorises)."""
    for x in range(dst.shape[0]):
        dst[x] += a[x]
