"""AffinityFilter as a fast kernel (Isik21 eq. (4), (6)); defined in rtdenoise.ops.affinity_filter.

Row-vectorised: one output row (runs of up to TILE pixels) per parallel iteration. For every
tap (i, j) the pixels whose neighbour lies inside the image form one contiguous run x in
[x0, x1) (taps outside the image are not visited: weight 0), processed by branch-free loops
along the row:

1. the squared feature distance, four feature channels per pass (`dist4`);
2. the weight w = exp(-a ||f_p - f_q||^2), fused with the last four channels (`_weights4`,
   `common.exp_neg`: a polynomial exp that vectorises);
3. w into the denominator, w times the neighbour into the numerator, three colour channels
   in one pass (`_accumulate3`; fusing 2 and 3 into one loop was slower: register spills).

The loops index with unsigned integers (`uintp`): a signed run-time offset (`row[x + off]`)
makes numba check every index for wrap-around, which stops the vectorisation (measured 16x
slower), and slicing the rows instead costs reference-count atomics on every slice, which
the two threads contend for (2.3x slower on 64-pixel rows). The centre tap starts the sums
with c_p (eq. (4)).
`spatial_sums`, `affinity_taps` and `normalise` are shared with TemporalAffinityFilter.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange, uintp

from rtdenoise.ops.affinity_filter import EPS, kernel_size_value

from .common import exp_neg
from .fast_kernel import fast_kernel
from .nonfinite import nan_on_nonfinite

_EPS = np.float32(EPS)
# Pixels of a row per work unit. Whole rows are fastest here (measured at 720p, 13 x 13:
# tiles of 256 px 26 % slower, 64 px 2.4x): the per-tap overhead outweighs the L1 cache.
TILE = 2048


@njit(cache=True, fastmath=True, error_model="numpy")
def dist4(dist, feats, guides, c, y, yy, off, x0, x1, first):
    """dist (= or +=) sum_{c' < c + 4} (feats[c', y, x] - guides[c', yy, x + off])^2."""
    for x in range(x0, x1):
        u, v = uintp(x), uintp(x + off)
        t0 = feats[c, y, u] - guides[c, yy, v]
        t1 = feats[c + 1, y, u] - guides[c + 1, yy, v]
        t2 = feats[c + 2, y, u] - guides[c + 2, yy, v]
        t3 = feats[c + 3, y, u] - guides[c + 3, yy, v]
        s = t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3
        dist[u] = s if first else dist[u] + s


@njit(cache=True, fastmath=True, error_model="numpy")
def dist1(dist, feats, guides, c, y, yy, off, x0, x1, first):
    """dist (= or +=) (feats[c, y, x] - guides[c, yy, x + off])^2."""
    for x in range(x0, x1):
        u, v = uintp(x), uintp(x + off)
        t0 = feats[c, y, u] - guides[c, yy, v]
        dist[u] = t0 * t0 if first else dist[u] + t0 * t0


@njit(cache=True, fastmath=True, error_model="numpy")
def _weights4(weight, dist, a, feats, guides, c, y, yy, off, x0, x1, first):
    """The last four feature channels (from c) of the distance, then w = exp(-a d)."""
    for x in range(x0, x1):
        u, v = uintp(x), uintp(x + off)
        t0 = feats[c, y, u] - guides[c, yy, v]
        t1 = feats[c + 1, y, u] - guides[c + 1, yy, v]
        t2 = feats[c + 2, y, u] - guides[c + 2, yy, v]
        t3 = feats[c + 3, y, u] - guides[c + 3, yy, v]
        s = t0 * t0 + t1 * t1 + t2 * t2 + t3 * t3
        if not first:
            s += dist[u]
        weight[u] = exp_neg(-a[u] * s)


@njit(cache=True, fastmath=True, error_model="numpy")
def _accumulate3(num, den, weight, values, yy, off, x0, x1):
    """den += w; num[c] += w * values[c, yy, x + off] for three channels, one pass."""
    for x in range(x0, x1):
        u, v = uintp(x), uintp(x + off)
        w = weight[u]
        den[u] += w
        num[0, u] += w * values[0, yy, v]
        num[1, u] += w * values[1, yy, v]
        num[2, u] += w * values[2, yy, v]


@njit(cache=True, fastmath=True, error_model="numpy")
def _weights(weight, dist, a, x0, x1):
    """weight = exp(-a * dist) (any feature count)."""
    for x in range(x0, x1):
        u = uintp(x)
        weight[u] = exp_neg(-a[u] * dist[u])


@njit(cache=True, fastmath=True, error_model="numpy")
def apply_mask(weight, mask, yy, off, x0, x1):
    """weight[x] *= mask[yy, x + off]."""
    for x in range(x0, x1):
        weight[uintp(x)] *= mask[yy, uintp(x + off)]


@njit(cache=True, fastmath=True, error_model="numpy")
def _accumulate(num, den, weight, values, yy, off, x0, x1):
    """den += w; num[c] += w * values[c, yy, x + off] for every channel c."""
    for x in range(x0, x1):
        den[uintp(x)] += weight[uintp(x)]
    for c in range(values.shape[0]):
        for x in range(x0, x1):
            u, v = uintp(x), uintp(x + off)
            num[c, u] += weight[u] * values[c, yy, v]


@njit(cache=True, fastmath=True, error_model="numpy")
def affinity_taps(
    num, den, feats, a, values, guides, mask, y, xa, xb, k, d, skip_centre, use_mask, dist, weight
):
    """Add the taps of one k x k kernel at dilation d to the sums of output pixels (y, x),
    x in [xa, xb).

    num (C, W), den (W): the sums; feats (D, H, W): the features, of which row y is compared;
    a (W): the bandwidth of row y; values (C, H, W): what the taps gather; guides (D, H, W):
    the features the taps compare with; mask (H, W): multiplies each tap's weight when
    use_mask; skip_centre: leave the centre tap out. dist, weight (W): scratch rows.
    """
    n_ch, h, w = values.shape
    n_feat = feats.shape[0]
    fused = n_feat >= 4 and n_feat % 4 == 0  # the last four channels go with the exp
    plain = n_feat - 4 if fused else n_feat  # channels summed into `dist` first
    r = k // 2
    for i in range(k):
        yy = y + (i - r) * d
        if yy < 0 or yy >= h:
            continue  # the whole tap row lies outside the image: weight 0
        for j in range(k):
            if skip_centre and i == r and j == r:
                continue
            off = (j - r) * d
            x0 = max(xa, -off)
            x1 = min(xb, w - off)
            if x1 <= x0:
                continue
            # 1-2. w = exp(-a ||f_p - f_q||^2) (Isik21 eq. (4) / (7)): the distance four
            # channels per pass, the last four fused with the exp
            for c in range(0, plain - plain % 4, 4):
                dist4(dist, feats, guides, c, y, yy, off, x0, x1, c == 0)
            for c in range(plain - plain % 4, plain):
                dist1(dist, feats, guides, c, y, yy, off, x0, x1, c == 0)
            if fused:
                _weights4(weight, dist, a, feats, guides, plain, y, yy, off, x0, x1, plain == 0)
            else:
                _weights(weight, dist, a, x0, x1)
            if use_mask:
                apply_mask(weight, mask, yy, off, x0, x1)
            # 3. the sums of eq. (6) / (8)
            if n_ch == 3:
                _accumulate3(num, den, weight, values, yy, off, x0, x1)
            else:
                _accumulate(num, den, weight, values, yy, off, x0, x1)


@njit(cache=True, fastmath=True, error_model="numpy")
def _scaled(dst, a, b):
    for x in range(dst.shape[0]):
        dst[x] = a[x] * b[x]


@njit(cache=True, fastmath=True, error_model="numpy")
def start_with_centre(num, den, image, centre, y, xa, xb):
    """num = c * image, den = c for output pixels (y, x), x in [xa, xb): the centre tap
    (Isik21 eq. (4)); image (C, H, W), centre (H, W)."""
    den[xa:xb] = centre[y, xa:xb]
    for c in range(num.shape[0]):
        _scaled(num[c, xa:xb], centre[y, xa:xb], image[c, y, xa:xb])


@njit(cache=True, fastmath=True, error_model="numpy")
def normalise(out, num, den, y, xa, xb):
    """out[:, y, xa:xb] = num / (1e-10 + den) (Isik21 eq. (6)); out (C, H, W)."""
    for x in range(xa, xb):
        den[x] = np.float32(1.0) / (_EPS + den[x])
    for c in range(num.shape[0]):
        _scaled(out[c, y, xa:xb], num[c, xa:xb], den[xa:xb])


@njit(cache=True, fastmath=True, error_model="numpy")
def spatial_sums(image, features, bandwidth, centre, mask, n, y, xa, xb, k, d):
    """The unnormalised sums of one tile of row y (Isik21 eq. (4)): the centre weight, then
    the dilated taps -> (num (C, W), den (W), and the dist / weight scratch rows for more
    taps). `mask` is not read (any (h, w) float32 array)."""
    n_ch, w = image.shape[1], image.shape[3]
    num = np.empty((n_ch, w), dtype=np.float32)
    den = np.empty(w, dtype=np.float32)
    dist = np.empty(w, dtype=np.float32)
    weight = np.empty(w, dtype=np.float32)
    start_with_centre(num, den, image[n], centre[n, 0], y, xa, xb)
    affinity_taps(
        num, den, features[n], bandwidth[n, 0, y], image[n], features[n], mask,
        y, xa, xb, k, d, True, False, dist, weight,
    )  # fmt: skip
    return num, den, dist, weight


@njit(parallel=True, cache=True, fastmath=True, error_model="numpy")
def _affinity_filter_nb(image, features, bandwidth, centre, out, k, d):
    n_img, h, w = image.shape[0], image.shape[2], image.shape[3]
    tiles = -(-w // TILE)
    no_mask = np.zeros((1, 1), dtype=np.float32)
    for unit in prange(n_img * h * tiles):
        u = np.int64(unit)  # the parfor index is unsigned: int64 keeps the arithmetic integer
        n = u // (h * tiles)
        y = (u // tiles) % h
        tile = u % tiles
        xa, xb = tile * TILE, min(w, (tile + 1) * TILE)
        sums = spatial_sums(image, features, bandwidth, centre, no_mask, n, y, xa, xb, k, d)
        normalise(out[n], sums[0], sums[1], y, xa, xb)


@fast_kernel("AffinityFilter")
@nan_on_nonfinite(5)
def affinity_filter(
    image: np.ndarray,
    features: np.ndarray,
    bandwidth: np.ndarray,
    centre: np.ndarray,
    kernel_size: np.ndarray,
    out: np.ndarray,
    dilation: int,
) -> None:
    """image (N, C, H, W), features (N, D, H, W), bandwidth and centre (N, 1, H, W), kernel
    size (scalar, odd) -> out (N, C, H, W)."""
    k = kernel_size_value(kernel_size)
    _affinity_filter_nb(image, features, bandwidth, centre, out, k, dilation)
