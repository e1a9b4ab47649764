"""SoftmaxKernelApply as a fast kernel; defined in rtdenoise.ops.softmax_kernel_apply.

KernelApply's row loop (`kernel_apply.apply_row`), on weights normalised per output row: the
row's k*k logits become softmax weights in a small row buffer (per pixel: max, exp, sum, scale;
exp vectorised, see `EXP2_POLY`). The normalised kernel never leaves the cache.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel
from .kernel_apply import apply_row

# exp(v) = 2^n * 2^f with n = floor(v log2 e), f in [0, 1): 2^f by a degree-5 polynomial
# (relative error 1.6e-7 in float32, fitted by reweighted least squares on [0, 1]) and 2^n by
# writing the exponent bits; unlike a call of expf, every step vectorises (AVX2: 8 lanes).
LOG2E = np.float32(1.4426950408889634)
EXP2_POLY = tuple(
    np.float32(c)
    for c in (
        0.9999999250646715,
        0.6931530731361506,
        0.24015361759712694,
        0.05582631641815092,
        0.008989342037999032,
        0.0018775758708015622,
    )
)
MIN_EXPONENT = np.float32(-126.0)  # 2^-126, the smallest normal float32: weights ~0 below


@njit(cache=True, fastmath=True)
def _softmax_row(logits, n, y, weights, bits, top, total):
    """weights[0, t, 0, x] = softmax over t of logits[n, t, y, x] (bits: (taps, W) int32
    scratch). Both 4-D arrays are indexed in full: a (taps, W) slice of one is typed
    non-contiguous, which keeps numba from vectorising the loops (2.5x slower)."""
    taps, w = logits.shape[1], logits.shape[3]
    c0, c1, c2, c3, c4, c5 = EXP2_POLY
    for x in range(w):
        top[x] = logits[n, 0, y, x]
    for t in range(1, taps):
        for x in range(w):
            top[x] = max(top[x], logits[n, t, y, x])
    for t in range(taps):  # 2^f into weights, 2^n as float32 bits into bits
        for x in range(w):
            v = max((logits[n, t, y, x] - top[x]) * LOG2E, MIN_EXPONENT)
            whole = np.floor(v)
            f = v - whole
            weights[0, t, 0, x] = c0 + f * (c1 + f * (c2 + f * (c3 + f * (c4 + f * c5))))
            bits[t, x] = (np.int32(whole) + np.int32(127)) << np.int32(23)
    scale = bits.view(np.float32)
    total[:] = 0.0
    for t in range(taps):
        for x in range(w):
            e = weights[0, t, 0, x] * scale[t, x]
            weights[0, t, 0, x] = e
            total[x] += e
    for x in range(w):
        total[x] = np.float32(1.0) / total[x]
    for t in range(taps):
        for x in range(w):
            weights[0, t, 0, x] *= total[x]


@njit(parallel=True, cache=True, fastmath=True)
def _softmax_kernel_apply_nb(image, logits, out, k, d):
    n_img, n_ch, h, w = image.shape
    p = (k // 2) * d
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        padded = np.empty((n_ch, w + 2 * p), dtype=np.float32)
        weights = np.empty((1, k * k, 1, w), dtype=np.float32)  # 4-D, as apply_row reads it
        bits = np.empty((k * k, w), dtype=np.int32)
        top = np.empty(w, dtype=np.float32)
        total = np.empty(w, dtype=np.float32)
        _softmax_row(logits, n, y, weights, bits, top, total)
        apply_row(image, weights, 0, 0, out, n, y, k, d, padded)


@fast_kernel("SoftmaxKernelApply")
def softmax_kernel_apply(
    image: np.ndarray, logits: np.ndarray, out: np.ndarray, kernel_size: int, dilation: int
) -> None:
    """image (N, C, H, W), logits (N, k*k, H, W) -> out (N, C, H, W)."""
    _softmax_kernel_apply_nb(image, logits, out, kernel_size, dilation)
