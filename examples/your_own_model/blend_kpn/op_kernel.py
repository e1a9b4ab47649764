"""NeighbourBlend as a fast kernel (numba): what the runtime runs by default, without torch."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rtdenoise.runtime.kernels import fast_kernel

from . import op_spec  # noqa: F401  (the spec, before its form)


@njit(parallel=True, cache=True, fastmath=True)
def _blend(image, weight, out):
    n_img, n_ch, h, w = image.shape
    for row in prange(n_img * n_ch * h):
        n = row // (n_ch * h)
        c = (row // h) % n_ch
        y = row % h
        for x in range(w):
            total = np.float32(0.0)
            for dy in range(-1, 2):
                yy = min(max(y + dy, 0), h - 1)
                for dx in range(-1, 2):
                    total += image[n, c, yy, min(max(x + dx, 0), w - 1)]
            v = image[n, c, y, x]
            out[n, c, y, x] = v + weight[n, 0, y, x] * (total / np.float32(9.0) - v)


@fast_kernel("NeighbourBlend")
def neighbour_blend(image: np.ndarray, weight: np.ndarray, out: np.ndarray) -> None:
    _blend(image, weight, out)
