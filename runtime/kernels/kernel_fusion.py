"""KernelFusion as a fast kernel (Fan21 kernel fusion); defined in rtdenoise.ops.kernel_fusion.

out[n, c] = sum_i softmax_i(logits[n])[i] * images[n, i*C + c],  C = channels(images) / S.
One output row per parallel iteration, every step a contiguous row operation: max over S,
exponentials of (logit - max) <= 0 with a vectorisable polynomial exp (numba has no SVML
here; libm exp is ~9x slower), normalisation, then one multiply-add per (i, c).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._common import add_into
from .fast_kernel import fast_kernel

_LOG2E = np.float32(1.4426950408889634)
_LN2_HI = np.float32(0.693145751953125)  # ln 2 split in two for an exact k * ln2_hi
_LN2_LO = np.float32(1.428606765330187e-06)
_EXP_MIN = np.float32(-80.0)  # exp(-80) ~ 1.8e-35: 2^k * p stays a normal float32


@njit(cache=True, fastmath=True)
def _exp_nonpositive(out, bits, a, m):
    """out = exp(f) and bits = k << 23 with a - m = k ln2 + f, |f| <= ln2 / 2 (a <= m).

    exp(f) by its degree-6 Taylor polynomial (relative error < 2e-7); `_times_pow2` then
    multiplies by 2^k. Below -80 the argument is clamped (exp(-80) ~ 2e-35 instead of less).
    Two passes so that both vectorise.
    """
    for x in range(out.shape[0]):
        v = max(a[x] - m[x], _EXP_MIN)
        k = np.floor(v * _LOG2E + np.float32(0.5))
        f = v - k * _LN2_HI - k * _LN2_LO
        p = np.float32(0.0013888889) * f + np.float32(0.008333333)
        p = p * f + np.float32(0.041666664)
        p = p * f + np.float32(0.16666666)
        p = p * f + np.float32(0.5)
        p = p * f + np.float32(1.0)
        out[x] = p * f + np.float32(1.0)
        bits[x] = np.int32(k) << np.int32(23)


@njit(cache=True, fastmath=True)
def _times_pow2(out, bits):
    """out *= 2^k, given bits = k << 23 and out in [0.5, 2): an integer add to the exponent."""
    ob = out.view(np.int32)
    for x in range(out.shape[0]):
        ob[x] += bits[x]


@njit(cache=True, fastmath=True)
def _max_acc(dst, a):
    for x in range(dst.shape[0]):
        dst[x] = max(dst[x], a[x])


@njit(cache=True, fastmath=True)
def _inverse(dst, a):
    for x in range(dst.shape[0]):
        dst[x] = np.float32(1.0) / a[x]


@njit(cache=True, fastmath=True)
def _scale(dst, a):
    for x in range(dst.shape[0]):
        dst[x] *= a[x]


@njit(cache=True, fastmath=True)
def _mul_row(out, p, src):
    for x in range(out.shape[0]):
        out[x] = p[x] * src[x]


@njit(cache=True, fastmath=True)
def _fma_row(out, p, src):
    for x in range(out.shape[0]):
        out[x] += p[x] * src[x]


@njit(parallel=True, cache=True, fastmath=True)
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
            _exp_nonpositive(prob[i], bits, logits[n, i, y], top)
            _times_pow2(prob[i], bits)
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
def kernel_fusion(images: np.ndarray, logits: np.ndarray, out: np.ndarray) -> None:
    """images (N, S*C, H, W), logits (N, S, H, W) -> out (N, C, H, W)."""
    _kernel_fusion_nb(images, logits, out)
