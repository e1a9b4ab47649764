"""CrossRegression as a fast kernel (Choi24 eqs. (4)-(7)); defined in
rtdenoise.ops.cross_regression. float64 throughout, like the other forms.

Three passes over the 2N regressions (A's variables against y^B, then B's against y^A):
1. per-pixel stack [y, albedo, normal, sigma, var, target] (14 planes), var from the in-image
   3x3 neighbours;
2. one parallel task per (regression, centre row); per centre, the 61 distinct sums of X^T W X
   and X^T W y (10 shared by the colour channels, 17 per channel) over its mirrored window in
   local accumulators (registers, not memory), then a 6 x 6 Cholesky solve per channel;
3. one parallel task per (regression, pixel row); per pixel, eq. (5) over the covering
   centres in local accumulators.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange, uintp

from rtdenoise.ops.cross_regression import centre_count, reconstruction_offsets

from .cross_bilateral_filter import mirror
from .fast_kernel import fast_kernel
from .nonfinite import nan_on_nonfinite

P = 6
NQ = 14  # y (3), albedo (3), normal (3), sigma, var, target (3)


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
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


@njit(cache=True, fastmath=True, error_model="numpy")
def _centre_sums(q, b, cy, cx, r, acc):
    """The 61 distinct sums of X^T W X and X^T W y over the mirrored window of centre (cy, cx)
    (10 shared by the channels: 1 and n; 17 per channel), in local accumulators."""
    h, w = q.shape[2], q.shape[3]
    c0, c1, c2 = q[b, 0, cy, cx], q[b, 1, cy, cx], q[b, 2, cy, cx]
    ca = (q[b, 3, cy, cx], q[b, 4, cy, cx], q[b, 5, cy, cx])
    cn0, cn1, cn2 = q[b, 6, cy, cx], q[b, 7, cy, cx], q[b, 8, cy, cx]
    csig, cvar = q[b, 9, cy, cx], q[b, 10, cy, cx]
    for k in range(61):
        acc[k] = 0.0
    for dy in range(-r, r + 1):
        sy = uintp(mirror(cy + dy, h))
        for dx in range(-r, r + 1):
            sx = uintp(mirror(cx + dx, w))
            d0 = q[b, 0, sy, sx] - c0
            d1 = q[b, 1, sy, sx] - c1
            d2 = q[b, 2, sy, sx] - c2
            wgt = math.exp(-(d0 * d0 + d1 * d1 + d2 * d2) / (cvar + q[b, 10, sy, sx] + 1e-4))
            wgt += 1e-7
            inv = 1.0 / (csig + q[b, 9, sy, sx] + 1e-2)
            n0 = q[b, 6, sy, sx] - cn0
            n1 = q[b, 7, sy, sx] - cn1
            n2 = q[b, 8, sy, sx] - cn2
            wn0, wn1, wn2 = wgt * n0, wgt * n1, wgt * n2
            acc[0] += wgt
            acc[1] += wn0
            acc[2] += wn1
            acc[3] += wn2
            acc[4] += wn0 * n0
            acc[5] += wn0 * n1
            acc[6] += wn0 * n2
            acc[7] += wn1 * n1
            acc[8] += wn1 * n2
            acc[9] += wn2 * n2
            for c in range(3):
                x1 = (d0 if c == 0 else (d1 if c == 1 else d2)) * inv
                x2 = q[b, 3 + c, sy, sx] - ca[c]
                t = q[b, 11 + c, sy, sx]
                wx1, wx2, wt = wgt * x1, wgt * x2, wgt * t
                k = uintp(10 + 17 * c)
                acc[k] += wx1
                acc[k + 1] += wx2
                acc[k + 2] += wx1 * x1
                acc[k + 3] += wx1 * x2
                acc[k + 4] += wx2 * x2
                acc[k + 5] += wx1 * n0
                acc[k + 6] += wx1 * n1
                acc[k + 7] += wx1 * n2
                acc[k + 8] += wx2 * n0
                acc[k + 9] += wx2 * n1
                acc[k + 10] += wx2 * n2
                acc[k + 11] += wt
                acc[k + 12] += wx1 * t
                acc[k + 13] += wx2 * t
                acc[k + 14] += wt * n0
                acc[k + 15] += wt * n1
                acc[k + 16] += wt * n2


@njit(cache=True, fastmath=True, error_model="numpy")
def _solve(acc, c, beta):
    """beta (6,) of channel c: Cholesky solve of the ridge system assembled from the sums."""
    a = np.empty((P, P))
    rhs = np.empty(P)
    k = 10 + 17 * c
    a[0, 0] = acc[0]
    a[0, 1] = acc[k]
    a[0, 2] = acc[k + 1]
    a[0, 3] = acc[1]
    a[0, 4] = acc[2]
    a[0, 5] = acc[3]
    a[1, 1] = acc[k + 2]
    a[1, 2] = acc[k + 3]
    a[1, 3] = acc[k + 5]
    a[1, 4] = acc[k + 6]
    a[1, 5] = acc[k + 7]
    a[2, 2] = acc[k + 4]
    a[2, 3] = acc[k + 8]
    a[2, 4] = acc[k + 9]
    a[2, 5] = acc[k + 10]
    a[3, 3] = acc[4]
    a[3, 4] = acc[5]
    a[3, 5] = acc[6]
    a[4, 4] = acc[7]
    a[4, 5] = acc[8]
    a[5, 5] = acc[9]
    for i in range(P):
        a[i, i] += 1e-3
        rhs[i] = acc[k + 11 + i]
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


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _regress(q, beta, window, stride):
    """beta (B, Hc, Wc, 3, 6): the ridge regression of every centre."""
    nb = q.shape[0]
    hc, wc = beta.shape[1], beta.shape[2]
    r = window // 2
    for task in prange(nb * hc):
        b = task // hc
        i = task - b * hc
        acc = np.empty(61)
        for j in range(wc):
            _centre_sums(q, b, stride * i, stride * j, r, acc)
            for c in range(3):
                _solve(acc, c, beta[b, i, j, c])


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _reconstruct(q, beta, out, window, stride, lo, hi):
    """out (B, 3, H, W) float64: eq. (5) over the covering centres, clamped >= 0."""
    nb, _, h, w = q.shape
    hc, wc = beta.shape[1], beta.shape[2]
    r = window // 2
    for row in prange(nb * h):
        b = row // h
        y = row - b * h
        for x in range(w):
            p0, p1, p2 = q[b, 0, y, x], q[b, 1, y, x], q[b, 2, y, x]
            psig, pvar = q[b, 9, y, x], q[b, 10, y, x]
            num0 = 0.0
            num1 = 0.0
            num2 = 0.0
            den = 0.0
            for dj in range(-lo, hi + 1):
                jy = y // stride + dj
                if jy < 0 or jy >= hc or abs(y - stride * jy) > r:
                    continue
                cy = stride * jy
                for di in range(-lo, hi + 1):
                    ix = x // stride + di
                    if ix < 0 or ix >= wc or abs(x - stride * ix) > r:
                        continue
                    cx = stride * ix
                    dy0 = p0 - q[b, 0, cy, cx]
                    dy1 = p1 - q[b, 1, cy, cx]
                    dy2 = p2 - q[b, 2, cy, cx]
                    spread = q[b, 10, cy, cx] + pvar + 1e-4
                    wgt = math.exp(-(dy0 * dy0 + dy1 * dy1 + dy2 * dy2) / spread) + 1e-7
                    inv = 1.0 / (q[b, 9, cy, cx] + psig + 1e-2)
                    n0 = q[b, 6, y, x] - q[b, 6, cy, cx]
                    n1 = q[b, 7, y, x] - q[b, 7, cy, cx]
                    n2 = q[b, 8, y, x] - q[b, 8, cy, cx]
                    for c in range(3):
                        co = beta[b, jy, ix, c]
                        dyc = dy0 if c == 0 else (dy1 if c == 1 else dy2)
                        x2 = q[b, 3 + c, y, x] - q[b, 3 + c, cy, cx]
                        pred = co[0] + co[1] * dyc * inv + co[2] * x2
                        pred += co[3] * n0 + co[4] * n1 + co[5] * n2
                        if c == 0:
                            num0 += wgt * pred
                        elif c == 1:
                            num1 += wgt * pred
                        else:
                            num2 += wgt * pred
                    den += wgt
            out[b, 0, y, x] = max(num0 / den, 0.0)
            out[b, 1, y, x] = max(num1 / den, 0.0)
            out[b, 2, y, x] = max(num2 / den, 0.0)


@fast_kernel("CrossRegression")
@nan_on_nonfinite(4)
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
