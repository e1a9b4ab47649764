"""WeightSharingFilter as a fast kernel (Fan21); defined in rtdenoise.ops.weight_sharing_filter.

out[:, i*C + c] = boxsum_s(w_i * image_c) / boxsum_s(w_i)  (0 where boxsum_s(w_i) <= 0),
s = size_min + i * size_step, zero-padded s x s boxes.

Box sums in O(1) per pixel whatever s, without the cancellation of running sums or summed-area
tables (w spans exp(-20)..exp(20) and images reach 1e4: a running sum that once held a huge
value cannot return to a tiny one; a float64 summed-area table fails too). Van Herk /
Gil-Werman for sums: cut the zero-padded line into blocks of s; the window [a, a + s - 1] is
the suffix sum of a's block from a plus the prefix sum of the next block up to a + s - 1 (or
one whole block when a is a block start), so every sum only adds in-window terms: the
accuracy of direct summation at 3 additions per pixel per pass.

One parallel task per (image, size, strip of ~STRIP_ROWS rows); per block of s rows, for the
C numerator planes w_i * image_c and the denominator plane w_i: vertical pass on whole rows
(streaming the raw rows of the next block), then horizontal pass on the block stored
block-transposed (the scans inside the blocks become long contiguous row operations), then
out = numerator * (1 / denominator) written back in natural order. Cost per size does not
depend on s (measured at 720p: s = 3 and s = 13 take the same time).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from rtdenoise.ops.weight_sharing_filter import attrs_to_sizes

from .common import add_into
from .fast_kernel import fast_kernel

STRIP_ROWS = 96  # output rows per parallel task (rounded to whole blocks of s)


@njit(cache=True, fastmath=True)
def _mul(dst, a, b):
    """dst = a * b."""
    for x in range(dst.shape[0]):
        dst[x] = a[x] * b[x]


@njit(cache=True, fastmath=True)
def _add(dst, a, b):
    """dst = a + b (three distinct rows: in-place forms fail LLVM's alias check, unvectorised)."""
    for x in range(dst.shape[0]):
        dst[x] = a[x] + b[x]


@njit(cache=True, fastmath=True)
def _reciprocal(out, den):
    """out = 1 / den where den > 0, else 0 (so that num * out is 0 there)."""
    for x in range(out.shape[0]):
        d = den[x]
        safe = d if d > 0.0 else 1.0
        v = 1.0 / safe
        out[x] = v if d > 0.0 else 0.0


@njit(cache=True, fastmath=True)
def _source_rows(image, weights, n, i, p, y0, rows):
    """rows[t] = plane p of source row y0 + t (w_i * image_p, or w_i for p == C); 0 outside."""
    n_ch, h = image.shape[1], image.shape[2]
    for t in range(rows.shape[0]):
        y = y0 + t
        if y < 0 or y >= h:
            rows[t] = 0.0
        elif p < n_ch:
            _mul(rows[t], weights[n, i, y], image[n, p, y])
        else:
            rows[t] = weights[n, i, y]


@njit(cache=True, fastmath=True)
def _vertical(cur, vpre, t, q_row):
    """q_row = vertical box sum for row t of the block: suffix of this block from t plus the
    prefix of the next block up to t - 1 (or the whole block at t = 0)."""
    if t == 0:
        q_row[:] = cur[0]
    else:
        _add(q_row, cur[t], vpre[t - 1])


@njit(cache=True, fastmath=True)
def _horizontal(cur, vpre, s, r, q, qt, suf):
    """suf[j, t*nb + b] = s x s box sum of output row t of the block at column x = b*s + j.

    Vertical sums (cur, vpre) row by row into the zero-padded row q (nb, s), stored
    block-transposed, qt[j, t*nb + b] = q[b, j], so that the horizontal scans inside the
    blocks run over j as long contiguous row operations (all rows and blocks at once).
    (Indices come from `range` or views: numba's negative-index handling stops LLVM
    vectorising.)
    """
    nb = q.shape[0]
    width = cur.shape[1]
    q_row = q.reshape(nb * s)[r : r + width]
    for t in range(s):
        _vertical(cur, vpre, t, q_row)
        qt_t = qt[:, t * nb : (t + 1) * nb]
        for j in range(s):
            for b in range(nb):
                qt_t[j, b] = q[b, j]
    m = qt.shape[1]
    suf[s - 1, :] = qt[s - 1, :]
    for j in range(s - 2, -1, -1):  # suffix sums within each block
        _add(suf[j], suf[j + 1], qt[j])
    for j in range(1, s - 1):  # prefix sums within each block, in place
        add_into(qt[j], qt[j - 1])
    # window at x = b*s + j: suffix of block b from j + prefix of block b + 1 up to j - 1
    for j in range(1, s):
        add_into(suf[j, : m - 1], qt[j - 1, 1:])


@njit(parallel=True, cache=True, fastmath=True)
def _wsf_nb(image, weights, out, sizes, task_n, task_i, task_b0, task_b1):
    n_ch, h, w = image.shape[1], image.shape[2], image.shape[3]
    planes = n_ch + 1
    for task in prange(task_n.shape[0]):
        n, i = task_n[task], task_i[task]
        b0, b1 = task_b0[task], task_b1[task]
        s = sizes[i]
        r = s // 2
        nb = (w + 2 * r + s - 1) // s
        m = s * nb
        cur = np.empty((planes, s, w), dtype=np.float32)  # raw, then suffix sums of block b
        nxt = np.empty((planes, s, w), dtype=np.float32)  # raw rows of block b + 1
        vpre = np.empty((planes, s, w), dtype=np.float32)  # prefix sums of block b + 1
        q = np.zeros((nb, s), dtype=np.float32)
        qt = np.empty((s, m), dtype=np.float32)
        suf = np.empty((s, m), dtype=np.float32)
        inv = np.empty((s, m), dtype=np.float32)  # 1 / denominator (0 where it is 0)
        for p in range(planes):
            _source_rows(image, weights, n, i, p, b0 * s - r, cur[p])
        for b in range(b0, b1):
            # vertical vHGW: padded rows b*s + t, i.e. source rows b*s + t - r
            for p in range(planes):
                _source_rows(image, weights, n, i, p, (b + 1) * s - r, nxt[p])
                for t in range(s - 2, -1, -1):
                    add_into(cur[p, t], cur[p, t + 1])
                vpre[p, 0, :] = nxt[p, 0, :]
                for t in range(1, s - 1):
                    _add(vpre[p, t], vpre[p, t - 1], nxt[p, t])
            # horizontal vHGW, the denominator first; un-transpose into the output, divided
            _horizontal(cur[n_ch], vpre[n_ch], s, r, q, qt, suf)
            for j in range(s):
                _reciprocal(inv[j], suf[j])
            for c in range(n_ch):
                _horizontal(cur[c], vpre[c], s, r, q, qt, suf)
                for t in range(min(s, h - b * s)):
                    out_row = out[n, i * n_ch + c, b * s + t]
                    num_t = suf[:, t * nb : (t + 1) * nb]
                    inv_t = inv[:, t * nb : (t + 1) * nb]
                    for j in range(s):
                        for bb in range((w - j + s - 1) // s):
                            out_row[bb * s + j] = num_t[j, bb] * inv_t[j, bb]
            cur, nxt = nxt, cur


def _tasks(n_img: int, h: int, sizes: list[int]) -> tuple[np.ndarray, ...]:
    """(image, size, first block, end block) per task: strips of ~STRIP_ROWS output rows."""
    rows = []
    for i, s in enumerate(sizes):
        per = max(1, round(STRIP_ROWS / s))
        blocks = -(-h // s)
        for n in range(n_img):
            for b0 in range(0, blocks, per):
                rows.append((n, i, b0, min(b0 + per, blocks)))
    return tuple(np.ascontiguousarray(col, dtype=np.int64) for col in np.array(rows).T)


@fast_kernel("WeightSharingFilter")
def weight_sharing_filter(
    image: np.ndarray,
    weights: np.ndarray,
    out: np.ndarray,
    size_min: int,
    size_step: int,
    count: int,
) -> None:
    """image (N, C, H, W), weights (N, count, H, W) >= 0 -> out (N, count*C, H, W)."""
    sizes = attrs_to_sizes(size_min, size_step, count)
    _wsf_nb(
        image,
        weights,
        out,
        np.array(sizes, np.int64),
        *_tasks(image.shape[0], image.shape[2], sizes),
    )
