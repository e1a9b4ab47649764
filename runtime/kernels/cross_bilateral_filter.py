"""CrossBilateralFilter as a fast kernel (Choi24 eq. (9)); defined in
rtdenoise.ops.cross_bilateral_filter.

Row-vectorised: one output row per parallel iteration. For each window row the source row of
the 12 guide channels (pilots, albedo, normal) is copied once into a mirrored, padded buffer;
each tap is then one branch-free loop over the row that forms the four squared distances,
both weights and adds the 40 sums (4 + 4 + 16 + 16 output channels) into row accumulators.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(cache=True)
def mirror(k: int, n: int) -> int:
    """k reflected into [0, n) without repeating the edge (period 2 (n - 1))."""
    period = 2 * (n - 1)
    a = abs(k) % period
    return period - a if a >= n else a


@njit(cache=True, fastmath=True)
def _tap_row(pad, cen, band, off, dist_p, acc):
    """Add tap `off` (padded column x + off) of one window row to the row sums `acc` (40, W)."""
    for x in range(acc.shape[1]):
        q = x + off
        da = 0.0
        db = 0.0
        dr = 0.0
        dn = 0.0
        for c in range(3):
            e = pad[c, q] - cen[c, x]
            da += e * e
            e = pad[3 + c, q] - cen[3 + c, x]
            db += e * e
            e = pad[6 + c, q] - cen[6 + c, x]
            dr += e * e
            e = pad[9 + c, q] - cen[9 + c, x]
            dn += e * e
        shared = band[2, x] * dr + band[3, x] * dn + band[4, x] * dist_p
        ma = math.exp(-band[0, x] * da - shared)
        mb = math.exp(-band[1, x] * db - shared)
        for key in range(2):
            m = ma if key == 0 else mb
            dist_f = da if key == 0 else db
            base = 4 * key  # sum_a: acc 0..3, sum_b: acc 4..7
            dbase = 8 + 16 * key  # dsum_a: acc 8..23, dsum_b: acc 24..39
            f0 = pad[3 * key, q]
            f1 = pad[3 * key + 1, q]
            f2 = pad[3 * key + 2, q]
            acc[base, x] += m * f0
            acc[base + 1, x] += m * f1
            acc[base + 2, x] += m * f2
            acc[base + 3, x] += m
            for k in range(4):
                if k == 0:
                    md = m * dist_f
                elif k == 1:
                    md = m * dr
                elif k == 2:
                    md = m * dn
                else:
                    md = m * dist_p
                j = dbase + 4 * k
                acc[j, x] += md * f0
                acc[j + 1, x] += md * f1
                acc[j + 2, x] += md * f2
                acc[j + 3, x] += md


@njit(parallel=True, cache=True, fastmath=True)
def _cbf_nb(pa, pb, albedo, normal, band, sum_a, sum_b, dsum_a, dsum_b, window):
    n_img, _, h, w = pa.shape
    r = window // 2
    inv_r2 = 1.0 / (r * r)
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        cen = np.empty((12, w), dtype=np.float32)
        pad = np.empty((12, w + 2 * r), dtype=np.float32)
        acc = np.zeros((40, w), dtype=np.float32)
        for c in range(3):
            cen[c] = pa[n, c, y]
            cen[3 + c] = pb[n, c, y]
            cen[6 + c] = albedo[n, c, y]
            cen[9 + c] = normal[n, c, y]
        band_row = band[n, :, y]
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
                dist_p = np.float32(((iy - r) ** 2 + (ix - r) ** 2) * inv_r2)
                _tap_row(pad, cen, band_row, ix, dist_p, acc)
        for c in range(4):
            sum_a[n, c, y] = acc[c]
            sum_b[n, c, y] = acc[4 + c]
        for c in range(16):
            dsum_a[n, c, y] = acc[8 + c]
            dsum_b[n, c, y] = acc[24 + c]


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
