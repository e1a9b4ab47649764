"""Helpers shared by the numba kernels (no torch: runtime/ must run without it)."""

from __future__ import annotations

import numpy as np


def as_f32c(a: np.ndarray, name: str) -> np.ndarray:
    """`a` as a writable C-contiguous float32 array (one numba specialisation per kernel)."""
    a = np.asarray(a)
    if a.dtype != np.float32 or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(a, dtype=np.float32, order="C", copy=True)
    if a.ndim != 4:
        raise ValueError(f"{name} must be 4-D (N, C, H, W), got shape {a.shape}")
    return a
