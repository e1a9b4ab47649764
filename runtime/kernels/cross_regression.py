"""CrossRegression as a fast kernel (Choi24 eqs. (4)-(7)); defined in
rtdenoise.ops.cross_regression. float64 throughout, like the other forms.

Three passes over the 2N regressions (A's variables against y^B, then B's against y^A):
1. per-pixel stack [y, albedo, normal, sigma, var, target] (14 planes), var from the in-image
   3x3 neighbours;
2. one parallel task per (regression, centre row): for each window row and column offset the
   window pixels of all the row's centres are read through a precomputed mirrored column table,
   and the 61 distinct sums of X^T W X and X^T W y (10 shared by the colour channels, 17 per
   channel) are accumulated in row arrays; then a 6 x 6 Cholesky solve per centre and channel;
3. one parallel task per (regression, pixel row): eq. (5) over the covering centres, each
   centre offset one branch-free loop over the row (validity as a 0/1 factor).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rtdenoise.ops.cross_regression import centre_count, reconstruction_offsets

from .cross_bilateral_filter import mirror
from .fast_kernel import fast_kernel

P = 6
NQ = 14  # y (3), albedo (3), normal (3), sigma, var, target (3)


@njit(parallel=True, cache=True, fastmath=True)
def _stack(y, target, albedo, normal, q):
    """q (B, 14, H, W) float64 from the float32 inputs; var over the in-image 3x3 neighbours."""
    nb, _, h, w = y.shape
    for row in prange(nb * h):
        b = row // h
        yy = row - b * h
        for c in range(3):
            for x in range(w):
                q[b, c, yy, x] = y[b, c, yy, x]
                q[b, 3 + c, yy, x] = albedo[b, c, yy, x]
                q[b, 6 + c, yy, x] = normal[b, c, yy, x]
                q[b, 11 + c, yy, x] = target[b, c, yy, x]
        y0, y1 = max(0, yy - 1), min(h, yy + 2)
        for x in range(w):
            x0, x1 = max(0, x - 1), min(w, x + 2)
            count = (y1 - y0) * (x1 - x0) - 1
            var = 0.0
            for c in range(3):
                total = 0.0
                for sy in range(y0, y1):
                    for sx in range(x0, x1):
                        total += y[b, c, sy, sx]
                centre = np.float64(y[b, c, yy, x])
                d = centre - (total - centre) / count
                var += d * d
            q[b, 9, yy, x] = math.sqrt(var)
            q[b, 10, yy, x] = var


@njit(cache=True, fastmath=True)
def _accumulate(q, sy, cols, cen, acc):
    """Add the window pixels (row sy, columns cols[j]) of every centre j of a centre row."""
    for j in range(cols.shape[0]):
        sx = cols[j]
        dy0 = q[0, sy, sx] - cen[0, j]
        dy1 = q[1, sy, sx] - cen[1, j]
        dy2 = q[2, sy, sx] - cen[2, j]
        wgt = (
            math.exp(-(dy0 * dy0 + dy1 * dy1 + dy2 * dy2) / (cen[10, j] + q[10, sy, sx] + 1e-4))
            + 1e-7
        )
        inv = 1.0 / (cen[9, j] + q[9, sy, sx] + 1e-2)
        n0 = q[6, sy, sx] - cen[6, j]
        n1 = q[7, sy, sx] - cen[7, j]
        n2 = q[8, sy, sx] - cen[8, j]
        wn0, wn1, wn2 = wgt * n0, wgt * n1, wgt * n2
        # shared by the channels: 1, n (x0 and x3..5)
        acc[0, j] += wgt
        acc[1, j] += wn0
        acc[2, j] += wn1
        acc[3, j] += wn2
        acc[4, j] += wn0 * n0
        acc[5, j] += wn0 * n1
        acc[6, j] += wn0 * n2
        acc[7, j] += wn1 * n1
        acc[8, j] += wn1 * n2
        acc[9, j] += wn2 * n2
        for c in range(3):
            x1 = (dy0 if c == 0 else (dy1 if c == 1 else dy2)) * inv
            x2 = q[3 + c, sy, sx] - cen[3 + c, j]
            t = q[11 + c, sy, sx]
            wx1, wx2, wt = wgt * x1, wgt * x2, wgt * t
            k = 10 + 17 * c
            acc[k, j] += wx1
            acc[k + 1, j] += wx2
            acc[k + 2, j] += wx1 * x1
            acc[k + 3, j] += wx1 * x2
            acc[k + 4, j] += wx2 * x2
            acc[k + 5, j] += wx1 * n0
            acc[k + 6, j] += wx1 * n1
            acc[k + 7, j] += wx1 * n2
            acc[k + 8, j] += wx2 * n0
            acc[k + 9, j] += wx2 * n1
            acc[k + 10, j] += wx2 * n2
            acc[k + 11, j] += wt
            acc[k + 12, j] += wx1 * t
            acc[k + 13, j] += wx2 * t
            acc[k + 14, j] += wt * n0
            acc[k + 15, j] += wt * n1
            acc[k + 16, j] += wt * n2


@njit(cache=True, fastmath=True)
def _solve(acc, j, c, beta):
    """beta (6,) of channel c of centre j: Cholesky solve of the assembled ridge system."""
    a = np.empty((P, P))
    rhs = np.empty(P)
    k = 10 + 17 * c
    a[0, 0] = acc[0, j]
    a[0, 1] = acc[k, j]
    a[0, 2] = acc[k + 1, j]
    a[0, 3] = acc[1, j]
    a[0, 4] = acc[2, j]
    a[0, 5] = acc[3, j]
    a[1, 1] = acc[k + 2, j]
    a[1, 2] = acc[k + 3, j]
    a[1, 3] = acc[k + 5, j]
    a[1, 4] = acc[k + 6, j]
    a[1, 5] = acc[k + 7, j]
    a[2, 2] = acc[k + 4, j]
    a[2, 3] = acc[k + 8, j]
    a[2, 4] = acc[k + 9, j]
    a[2, 5] = acc[k + 10, j]
    a[3, 3] = acc[4, j]
    a[3, 4] = acc[5, j]
    a[3, 5] = acc[6, j]
    a[4, 4] = acc[7, j]
    a[4, 5] = acc[8, j]
    a[5, 5] = acc[9, j]
    for i in range(P):
        a[i, i] += 1e-3
        rhs[i] = acc[k + 11 + i, j]
    low = np.zeros((P, P))
    for i in range(P):
        for m in range(i + 1):
            s = a[m, i]  # upper triangle holds the sums
            for t in range(m):
                s -= low[i, t] * low[m, t]
            low[i, m] = math.sqrt(s) if i == m else s / low[m, m]
    z = np.empty(P)
    for i in range(P):
        s = rhs[i]
        for t in range(i):
            s -= low[i, t] * z[t]
        z[i] = s / low[i, i]
    for i in range(P - 1, -1, -1):
        s = z[i]
        for t in range(i + 1, P):
            s -= low[t, i] * beta[t]
        beta[i] = s / low[i, i]


@njit(parallel=True, cache=True, fastmath=True)
def _regress(q, beta, window, stride):
    """beta (B, Hc, Wc, 3, 6): the ridge regression of every centre."""
    nb, _, h, w = q.shape
    hc, wc = beta.shape[1], beta.shape[2]
    r = window // 2
    cols_of = np.empty((window, wc), dtype=np.int64)
    for dx in range(window):
        for j in range(wc):
            cols_of[dx, j] = mirror(stride * j + dx - r, w)
    for task in prange(nb * hc):
        b = task // hc
        i = task - b * hc
        cy = stride * i
        cen = np.empty((NQ, wc))
        for c in range(NQ):
            for j in range(wc):
                cen[c, j] = q[b, c, cy, stride * j]
        acc = np.zeros((61, wc))
        for dy in range(window):
            sy = mirror(cy + dy - r, h)
            for dx in range(window):
                _accumulate(q[b], sy, cols_of[dx], cen, acc)
        for j in range(wc):
            for c in range(3):
                _solve(acc, j, c, beta[b, i, j, c])


@njit(parallel=True, cache=True, fastmath=True)
def _reconstruct(q, beta, out, window, stride, lo, hi):
    """out (B, 3, H, W) float64: eq. (5) over the covering centres, clamped >= 0."""
    nb, _, h, w = q.shape
    hc, wc = beta.shape[1], beta.shape[2]
    r = window // 2
    for row in prange(nb * h):
        b = row // h
        y = row - b * h
        num = np.zeros((3, w))
        den = np.zeros(w)
        for dj in range(-lo, hi + 1):
            jy = y // stride + dj
            if jy < 0 or jy >= hc or abs(y - stride * jy) > r:
                continue
            cy = stride * jy
            for di in range(-lo, hi + 1):
                for x in range(w):
                    ix = x // stride + di
                    ok = 1.0 if (ix >= 0 and ix < wc and abs(x - stride * ix) <= r) else 0.0
                    ix = min(max(ix, 0), wc - 1)
                    cx = stride * ix
                    dy0 = q[b, 0, y, x] - q[b, 0, cy, cx]
                    dy1 = q[b, 1, y, x] - q[b, 1, cy, cx]
                    dy2 = q[b, 2, y, x] - q[b, 2, cy, cx]
                    spread = q[b, 10, cy, cx] + q[b, 10, y, x] + 1e-4
                    wgt = ok * (math.exp(-(dy0 * dy0 + dy1 * dy1 + dy2 * dy2) / spread) + 1e-7)
                    inv = 1.0 / (q[b, 9, cy, cx] + q[b, 9, y, x] + 1e-2)
                    n0 = q[b, 6, y, x] - q[b, 6, cy, cx]
                    n1 = q[b, 7, y, x] - q[b, 7, cy, cx]
                    n2 = q[b, 8, y, x] - q[b, 8, cy, cx]
                    for c in range(3):
                        co = beta[b, jy, ix, c]
                        dyc = dy0 if c == 0 else (dy1 if c == 1 else dy2)
                        x2 = q[b, 3 + c, y, x] - q[b, 3 + c, cy, cx]
                        pred = co[0] + co[1] * dyc * inv + co[2] * x2
                        pred += co[3] * n0 + co[4] * n1 + co[5] * n2
                        num[c, x] += wgt * pred
                    den[x] += wgt
        for c in range(3):
            for x in range(w):
                out[b, c, y, x] = max(num[c, x] / den[x], 0.0)


@fast_kernel("CrossRegression")
def cross_regression(
    y_a: np.ndarray,
    y_b: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    pilot_a: np.ndarray,
    pilot_b: np.ndarray,
    window: int,
    stride: int,
) -> None:
    """Fill pilot_a, pilot_b (N, 3, H, W); see the op."""
    n, _, h, w = y_a.shape
    y = np.concatenate((y_a, y_b))
    target = np.concatenate((y_b, y_a))
    q = np.empty((2 * n, NQ, h, w))
    _stack(y, target, np.concatenate((albedo, albedo)), np.concatenate((normal, normal)), q)
    beta = np.empty((2 * n, centre_count(h, stride), centre_count(w, stride), 3, P))
    _regress(q, beta, window, stride)
    offsets = reconstruction_offsets(window, stride)
    out = np.empty((2 * n, 3, h, w))
    _reconstruct(q, beta, out, window, stride, -offsets.start, offsets.stop - 1)
    pilot_a[...] = out[:n]
    pilot_b[...] = out[n:]
