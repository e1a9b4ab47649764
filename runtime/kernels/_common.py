"""Helpers shared by the numba kernels (no torch: runtime/ must run without it)."""

from __future__ import annotations

import numpy as np
from numba import njit


def as_f32c(a: np.ndarray, name: str) -> np.ndarray:
    """`a` as a writable C-contiguous float32 array (one numba specialisation per kernel)."""
    a = np.asarray(a)
    if a.dtype != np.float32 or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(a, dtype=np.float32, order="C", copy=True)
    if a.ndim != 4:
        raise ValueError(f"{name} must be 4-D (N, C, H, W), got shape {a.shape}")
    return a


@njit(cache=True, fastmath=True)
def add_into(dst, a):
    """dst += a, element-wise over a contiguous float32 row (vectorises)."""
    for x in range(dst.shape[0]):
        dst[x] += a[x]
