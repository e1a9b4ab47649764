"""CrossBilateralFilter as a fast kernel (Choi24 eq. (9)); defined in
rtdenoise.ops.cross_bilateral_filter.

Row-vectorised: one output row per parallel iteration. For each window row the source row of
the 12 guide channels (pilots, albedo, normal) is copied once into a mirrored, padded buffer;
each tap is then three branch-free float32 loops over the row: the four squared distances and
both exponents, the two weights (`exp_row`: a polynomial exp LLVM vectorises), and the 40 sums
(4 + 4 + 16 + 16 output channels) into row accumulators.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .common import exp_row
from .fast_kernel import fast_kernel


@njit(cache=True)
def mirror(k: int, n: int) -> int:
    """k reflected into [0, n) without repeating the edge (period 2 (n - 1))."""
    if 0 <= k < n:
        return k
    period = 2 * (n - 1)
    a = abs(k) % period
    return period - a if a >= n else a


@njit(cache=True, fastmath=True)
def _distances(pad, cen, band, off, dist_p, d, arg_a, arg_b):
    """Squared distances d (4, W) of tap `off` (colour A, colour B, albedo, normal) and the
    exponents of m^A, m^B (eq. (9)); one branch-free float32 loop over the row."""
    for x in range(cen.shape[1]):
        q = x + off
        e0 = pad[0, q] - cen[0, x]
        e1 = pad[1, q] - cen[1, x]
        e2 = pad[2, q] - cen[2, x]
        da = e0 * e0 + e1 * e1 + e2 * e2
        e0 = pad[3, q] - cen[3, x]
        e1 = pad[4, q] - cen[4, x]
        e2 = pad[5, q] - cen[5, x]
        db = e0 * e0 + e1 * e1 + e2 * e2
        e0 = pad[6, q] - cen[6, x]
        e1 = pad[7, q] - cen[7, x]
        e2 = pad[8, q] - cen[8, x]
        dr = e0 * e0 + e1 * e1 + e2 * e2
        e0 = pad[9, q] - cen[9, x]
        e1 = pad[10, q] - cen[10, x]
        e2 = pad[11, q] - cen[11, x]
        dn = e0 * e0 + e1 * e1 + e2 * e2
        shared = band[2, x] * dr + band[3, x] * dn + band[4, x] * dist_p
        d[0, x] = da
        d[1, x] = db
        d[2, x] = dr
        d[3, x] = dn
        arg_a[x] = -(band[0, x] * da + shared)
        arg_b[x] = -(band[1, x] * db + shared)


@njit(cache=True, fastmath=True)
def _accumulate(pad, off, base, m, dist_f, dist_r, dist_n, dist_p, acc):
    """Add buffer `base`'s (0: A, 3: B) terms of one tap to its 20 row sums `acc` (20, W):
    [m f, m] then [m D_k f, m D_k] for k = colour, albedo, normal, position."""
    for x in range(acc.shape[1]):
        q = x + off
        w = m[x]
        f0 = pad[base, q]
        f1 = pad[base + 1, q]
        f2 = pad[base + 2, q]
        acc[0, x] += w * f0
        acc[1, x] += w * f1
        acc[2, x] += w * f2
        acc[3, x] += w
        wd = w * dist_f[x]
        acc[4, x] += wd * f0
        acc[5, x] += wd * f1
        acc[6, x] += wd * f2
        acc[7, x] += wd
        wd = w * dist_r[x]
        acc[8, x] += wd * f0
        acc[9, x] += wd * f1
        acc[10, x] += wd * f2
        acc[11, x] += wd
        wd = w * dist_n[x]
        acc[12, x] += wd * f0
        acc[13, x] += wd * f1
        acc[14, x] += wd * f2
        acc[15, x] += wd
        wd = w * dist_p
        acc[16, x] += wd * f0
        acc[17, x] += wd * f1
        acc[18, x] += wd * f2
        acc[19, x] += wd


@njit(parallel=True, cache=True, fastmath=True)
def _cbf_nb(pa, pb, albedo, normal, band, sum_a, sum_b, dsum_a, dsum_b, window):
    n_img, _, h, w = pa.shape
    r = window // 2
    inv_r2 = np.float32(1.0 / (r * r))
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        cen = np.empty((12, w), dtype=np.float32)
        pad = np.empty((12, w + 2 * r), dtype=np.float32)
        acc_a = np.zeros((20, w), dtype=np.float32)
        acc_b = np.zeros((20, w), dtype=np.float32)
        d = np.empty((4, w), dtype=np.float32)
        arg_a = np.empty(w, dtype=np.float32)
        arg_b = np.empty(w, dtype=np.float32)
        m_a = np.empty(w, dtype=np.float32)
        m_b = np.empty(w, dtype=np.float32)
        for c in range(3):
            cen[c] = pa[n, c, y]
            cen[3 + c] = pb[n, c, y]
            cen[6 + c] = albedo[n, c, y]
            cen[9 + c] = normal[n, c, y]
        band_row = np.ascontiguousarray(band[n, :, y])
        for iy in range(window):
            sy = mirror(y + iy - r, h)
            for x in range(w + 2 * r):
                sx = mirror(x - r, w)
                for c in range(3):
                    pad[c, x] = pa[n, c, sy, sx]
                    pad[3 + c, x] = pb[n, c, sy, sx]
                    pad[6 + c, x] = albedo[n, c, sy, sx]
                    pad[9 + c, x] = normal[n, c, sy, sx]
            for ix in range(window):
                dist_p = np.float32((iy - r) ** 2 + (ix - r) ** 2) * inv_r2
                _distances(pad, cen, band_row, ix, dist_p, d, arg_a, arg_b)
                exp_row(m_a, arg_a)
                exp_row(m_b, arg_b)
                _accumulate(pad, ix, 0, m_a, d[0], d[2], d[3], dist_p, acc_a)
                _accumulate(pad, ix, 3, m_b, d[1], d[2], d[3], dist_p, acc_b)
        for c in range(4):
            sum_a[n, c, y] = acc_a[c]
            sum_b[n, c, y] = acc_b[c]
        for c in range(16):
            dsum_a[n, c, y] = acc_a[4 + c]
            dsum_b[n, c, y] = acc_b[4 + c]


@fast_kernel("CrossBilateralFilter")
def cross_bilateral_filter(
    pilot_a: np.ndarray,
    pilot_b: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    band: np.ndarray,
    sum_a: np.ndarray,
    sum_b: np.ndarray,
    dsum_a: np.ndarray,
    dsum_b: np.ndarray,
    window: int,
) -> None:
    """Fill sum_a, sum_b (N, 4, H, W) and dsum_a, dsum_b (N, 16, H, W); see the op."""
    _cbf_nb(pilot_a, pilot_b, albedo, normal, band, sum_a, sum_b, dsum_a, dsum_b, window)
