"""SoftmaxKernelApply as a fast kernel; defined in rtdenoise.ops.softmax_kernel_apply.

One output row per parallel iteration, the softmax normalised after the sum:

    out[c, y, x] = (sum over taps t of e_t[x] image_c[tap t's shifted row][x]) / sum_t e_t[x],
    e_t = exp(logit_t - max over t of logit_t)

A first pass over the row's k*k logits takes the per-pixel maximum; then, tap by tap, the
exponentials (`exp_neg`, vectorised: numba has no SVML here) go into one row buffer and a
running total, and each channel accumulates e_t times its shifted source row
(KernelApply's edge-replicated row and FMA loop); one multiply by 1 / total at the end. The
normalised kernel is never stored: 0.91-0.93x the time of normalising a (k*k, W) weight
buffer first at AFN's sizes (benchmarks/README.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import exp_neg
from .fast_kernel import fast_kernel
from .kernel_apply import _fma_row, pad_source_rows


@njit(cache=True, fastmath=True)
def _exp_row(e, total, logit, top):
    """e = exp(logit - top), total += e, over a row (vectorises)."""
    for x in range(e.shape[0]):
        v = exp_neg(logit[x] - top[x])
        e[x] = v
        total[x] += v


@njit(parallel=True, cache=True, fastmath=True)
def _softmax_kernel_apply_nb(image, logits, out, k, d):
    n_img, n_ch, h, w = image.shape
    p = (k // 2) * d
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        padded = np.empty((n_ch, w + 2 * p), dtype=np.float32)
        e = np.empty(w, dtype=np.float32)
        top = logits[n, 0, y].copy()
        total = np.zeros(w, dtype=np.float32)
        for t in range(1, k * k):
            for x in range(w):
                top[x] = max(top[x], logits[n, t, y, x])
        for c in range(n_ch):
            out[n, c, y, :] = 0.0
        for i in range(k):
            pad_source_rows(image, n, y, i, k, d, padded)
            for j in range(k):
                _exp_row(e, total, logits[n, i * k + j, y], top)
                for c in range(n_ch):
                    _fma_row(out[n, c, y], e, padded[c], j * d)
        for x in range(w):
            total[x] = np.float32(1.0) / total[x]
        for c in range(n_ch):
            for x in range(w):
                out[n, c, y, x] *= total[x]


@fast_kernel("SoftmaxKernelApply")
def softmax_kernel_apply(
    image: np.ndarray, logits: np.ndarray, out: np.ndarray, kernel_size: int, dilation: int
) -> None:
    """image (N, C, H, W), logits (N, k*k, H, W) -> out (N, C, H, W)."""
    _softmax_kernel_apply_nb(image, logits, out, kernel_size, dilation)
