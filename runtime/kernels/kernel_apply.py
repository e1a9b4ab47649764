"""KernelApply as a fast kernel (Lee24 eq. (2)); defined in rtdenoise.ops.kernel_apply.

Row-vectorised: one output row per parallel iteration; for each kernel row i the source row
is copied once into an edge-replicated padded buffer, so the taps are branch-free contiguous
FMA loops  out_row[x] += kernel_row_t[x] * padded_row[x + j d], two taps per pass (fewer
accumulator loads/stores: ~10 % faster than one). The loops index with unsigned integers
(`uintp`): with a signed offset (`src[x + off]`) numba checks every index for wrap-around and
the loop stays scalar (5-7x slower; as in the affinity kernels).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, uintp

from .fast_kernel import fast_kernel


@njit(cache=True, fastmath=True)
def _pad_row(src, dst, p):
    """dst[p + x] = src[x]; dst[:p] = src[0]; dst[p + w:] = src[w - 1]."""
    w = src.shape[0]
    left = src[0]
    right = src[w - 1]
    for x in range(p):
        dst[x] = left
    for x in range(w):
        dst[p + x] = src[x]
    for x in range(p + w, dst.shape[0]):
        dst[x] = right


@njit(cache=True, fastmath=True)
def _fma_row(acc, weight, src, off):
    """acc[x] += weight[x] * src[x + off] over the whole row."""
    for x in range(acc.shape[0]):
        u = uintp(x)
        acc[u] += weight[u] * src[uintp(x + off)]


@njit(cache=True, fastmath=True)
def _fma2_row(acc, w0, w1, src, o0, o1):
    """acc[x] += w0[x] * src[x + o0] + w1[x] * src[x + o1] over the whole row."""
    for x in range(acc.shape[0]):
        u = uintp(x)
        acc[u] += w0[u] * src[uintp(x + o0)] + w1[u] * src[uintp(x + o1)]


@njit(cache=True, fastmath=True)
def pad_source_rows(image, n, y, i, k, d, padded):
    """padded[c] = channel c's source row for kernel row i of output row y (row y + (i - k // 2)
    d, clamped into the frame), edge-replicated by (k // 2) d on both sides."""
    yy = min(max(y + (i - k // 2) * d, 0), image.shape[2] - 1)
    for c in range(image.shape[1]):
        _pad_row(image[n, c, yy], padded[c], (k // 2) * d)


@njit(cache=True, fastmath=True)
def apply_row(image, kernel, kn, ky, out, n, y, k, d, padded):
    """out[n, :, y] = sum over taps t of kernel[kn, t, ky] * the tap's shifted image row
    (padded: (C, W + 2 r d) scratch). The kernel rows are read from a 4-D array, so that every
    row is a contiguous slice numba vectorises over (a (taps, W) slice would not be)."""
    n_ch = image.shape[1]
    for c in range(n_ch):
        out[n, c, y, :] = 0.0
    for i in range(k):
        pad_source_rows(image, n, y, i, k, d, padded)
        t0 = i * k
        for j in range(0, k - 1, 2):
            w0 = kernel[kn, t0 + j, ky]
            w1 = kernel[kn, t0 + j + 1, ky]
            for c in range(n_ch):
                _fma2_row(out[n, c, y], w0, w1, padded[c], j * d, (j + 1) * d)
        if k % 2 == 1:  # k is odd: the last tap of the row alone
            weight = kernel[kn, t0 + k - 1, ky]
            for c in range(n_ch):
                _fma_row(out[n, c, y], weight, padded[c], (k - 1) * d)


@njit(parallel=True, cache=True, fastmath=True)
def _kernel_apply_nb(image, kernel, out, k, d):
    n_img, n_ch, h, w = image.shape
    p = (k // 2) * d
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        padded = np.empty((n_ch, w + 2 * p), dtype=np.float32)
        apply_row(image, kernel, n, y, out, n, y, k, d, padded)


@fast_kernel("KernelApply")
def kernel_apply(
    image: np.ndarray, kernel: np.ndarray, out: np.ndarray, kernel_size: int, dilation: int
) -> None:
    """image (N, C, H, W), kernel (N, k*k, H, W) -> out (N, C, H, W)."""
    _kernel_apply_nb(image, kernel, out, kernel_size, dilation)
