"""KernelFusion as a fast kernel (Fan21 kernel fusion); defined in rtdenoise.ops.kernel_fusion.

out[n, c] = sum_i softmax_i(logits[n])[i] * images[n, i*C + c],  C = channels(images) / S.
One output row per parallel iteration, every step a contiguous row operation: max over S,
exponentials of (logit - max) <= 0 with the vectorisable polynomial exp of `common`,
normalisation, then one multiply-add per (i, c).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import add_into, exp_nonpositive, times_pow2
from .fast_kernel import fast_kernel
from .nonfinite import nan_on_nonfinite


@njit(cache=True, fastmath=True, error_model="numpy")
def _max_acc(dst, a):
    for x in range(dst.shape[0]):
        dst[x] = max(dst[x], a[x])


@njit(cache=True, fastmath=True, error_model="numpy")
def _inverse(dst, a):
    for x in range(dst.shape[0]):
        dst[x] = np.float32(1.0) / a[x]


@njit(cache=True, fastmath=True, error_model="numpy")
def _scale(dst, a):
    for x in range(dst.shape[0]):
        dst[x] *= a[x]


@njit(cache=True, fastmath=True, error_model="numpy")
def _mul_row(out, p, src):
    for x in range(out.shape[0]):
        out[x] = p[x] * src[x]


@njit(cache=True, fastmath=True, error_model="numpy")
def _fma_row(out, p, src):
    for x in range(out.shape[0]):
        out[x] += p[x] * src[x]


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _kernel_fusion_nb(images, logits, out):
    n_img, n_s, h, w = logits.shape
    n_ch = out.shape[1]
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        prob = np.empty((n_s, w), dtype=np.float32)
        top = np.empty(w, dtype=np.float32)
        total = np.empty(w, dtype=np.float32)
        bits = np.empty(w, dtype=np.int32)
        top[:] = logits[n, 0, y]
        for i in range(1, n_s):
            _max_acc(top, logits[n, i, y])
        for i in range(n_s):  # softmax, max subtracted
            exp_nonpositive(prob[i], bits, logits[n, i, y], top)
            times_pow2(prob[i], bits)
        total[:] = prob[0]
        for i in range(1, n_s):
            add_into(total, prob[i])
        _inverse(top, total)  # total >= 1 (the largest term is exp(0))
        for i in range(n_s):
            _scale(prob[i], top)
        for c in range(n_ch):
            _mul_row(out[n, c, y], prob[0], images[n, c, y])
            for i in range(1, n_s):
                _fma_row(out[n, c, y], prob[i], images[n, i * n_ch + c, y])


@fast_kernel("KernelFusion")
@nan_on_nonfinite(2, inputs=(1,))  # images only multiply: NaN reaches the output
def kernel_fusion(images: np.ndarray, logits: np.ndarray, out: np.ndarray) -> None:
    """images (N, S*C, H, W), logits (N, S, H, W) -> out (N, C, H, W)."""
    _kernel_fusion_nb(images, logits, out)
