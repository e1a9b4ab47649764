"""BilateralGrid as a fast kernel (Meng20); defined in rtdenoise.ops.bilateral_grid.

Linear in pixels plus cells, no per-pixel loop over cells: every pixel touches its 2 x 2 x 2
cells only. Three parallel passes (few, so that a loaded machine pays few thread wake-ups):

1. `_prepare`, per pixel row: each pixel's payload [r, g, b, 1] as one run of CELL = 4 floats,
   and its two depth cells and their tent weights (the row and column cells and weights are
   numpy tables: they depend on s only);
2. `_splat` (Meng20 eqs. (10)-(11)), per grid row (n, i): zero its cells, add T * payload from
   the pixel rows that reach it (each pixel row feeds two grid rows, so no two tasks write one
   cell; neighbouring pixels' sums for the same cells first add up in registers), divide each
   cell by its weight sum. The grid is (N, Gh, Gw, D, CELL): a cell is one contiguous run
   [3 channels, weight sum];
3. `_slice` (Meng20 eq. (13)), per pixel row: the same 8 corners of each pixel, cells with a
   positive weight sum only, sum T M / sum T.

C channels run 3 at a time (the weights do not depend on the image; a last group of 1 or 2 is
padded with zeros), so the hot loops have fixed-size cells. Grid offsets are unsigned
(`uintp`): numba checks signed indices for wrap-around on every access (measured at 720p on
nbg's inputs: 0.66-0.78x the time of signed offsets, the same bits).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit, prange, uintp

from rtdenoise.ops.bilateral_grid import GUIDE_MAX, GUIDE_RANGE, TENT_EPS, grid_shape

from .fast_kernel import fast_kernel

CELL = 4  # floats per grid cell: 3 channels and the weight sum; C channels go 3 at a time

_EPS = np.float32(TENT_EPS)
_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_HALF = np.float32(0.5)
_GMAX = np.float32(GUIDE_MAX)
_GRANGE = np.float32(GUIDE_RANGE)


def _tent_np(u: np.ndarray) -> np.ndarray:
    return np.maximum(_ONE - np.sqrt(u * u + _EPS), _ZERO)


def _axis_table(size: int, cell_size: int, cells: int) -> tuple[np.ndarray, ...]:
    """Per pixel of one axis: the two covering cells (clamped into the grid) and their tent
    weights (0 for a cell outside the grid), float32 as in the other forms."""
    t = (np.arange(size, dtype=np.float32) + _HALF) / np.float32(cell_size) - _HALF
    first = np.floor(t)
    u = t - first
    i0 = first.astype(np.int64)
    w0 = np.where(i0 >= 0, _tent_np(u), _ZERO).astype(np.float32)
    w1 = np.where(i0 + 1 < cells, _tent_np(u - _ONE), _ZERO).astype(np.float32)
    return np.clip(i0, 0, cells - 1), np.clip(i0 + 1, 0, cells - 1), w0, w1


@njit(cache=True, fastmath=True)
def _tent(u):
    v = _ONE - np.sqrt(u * u + _EPS)
    return v if v > _ZERO else _ZERO


@njit(parallel=True, cache=True, fastmath=True)
def _prepare(image, c0, guide, depth, hom, z0, z1, wz0, wz1):
    """Per pixel: hom = [image[c0 : c0 + 3] (0 past the last channel), 1], the splat payload as
    one aligned run of CELL floats; z0, z1 = offsets (cell index x CELL) of the two depth cells
    around z = (clamp(g, 0, 255) + 0.5) D / 256 (Meng20 eq. (12)), clamped into the grid;
    wz0, wz1 = their tent weights (0 outside the grid)."""
    n_img, n_ch, h, w = image.shape
    depth_f = np.float32(depth)
    for task in prange(n_img * h):
        n, y = task // h, task % h
        row = hom[n, y]
        for k in range(CELL - 1):
            if c0 + k < n_ch:
                src = image[n, c0 + k, y]
                for x in range(w):
                    row[x, k] = src[x]
            else:
                for x in range(w):
                    row[x, k] = _ZERO
        for x in range(w):
            row[x, CELL - 1] = _ONE
        g_row = guide[n, 0, y]
        for x in range(w):
            g = min(max(g_row[x], _ZERO), _GMAX)
            t = (g + _HALF) * depth_f / _GRANGE - _HALF
            first = np.floor(t)
            u = t - first
            i0 = min(max(int(first), -1), depth - 1)  # integer clamp: memory safe for any input
            z0[n, y, x] = max(i0, 0) * CELL
            z1[n, y, x] = min(i0 + 1, depth - 1) * CELL
            wz0[n, y, x] = _tent(u) if i0 >= 0 else _ZERO
            wz1[n, y, x] = _tent(u - _ONE) if i0 + 1 < depth else _ZERO


@njit(cache=True, fastmath=True)
def _add(grid, at, c0, c1, c2, c3):
    """grid[at : at + CELL] += [c0, c1, c2, c3]."""
    u = uintp(at)
    grid[u] += c0
    grid[u + uintp(1)] += c1
    grid[u + uintp(2)] += c2
    grid[u + uintp(3)] += c3


@njit(cache=True, fastmath=True)
def _normalise(cells):
    """cells (n, CELL) of sums [T image, T] -> [T image / T, T] (Meng20 eq. (10)); branch-free
    (an empty cell is all zeros and stays so), which LLVM vectorises: the splat at s = 4, D =
    64 (720p) took 9.4-10.0 ms with it, 14.0 with a branch per cell."""
    for j in range(cells.shape[0]):
        total = cells[j, CELL - 1]
        inv = _ONE / total if total > 0.0 else _ZERO
        for k in range(CELL - 1):
            cells[j, k] *= inv


@njit(cache=True, fastmath=True)
def _splat_row(grid, base, pixels, xo, wx, wy, za, zb, wza, wzb):
    """Add one pixel row's contributions to its column cells xo[x] (weights wy wx[x]) at depth
    cells za[x], zb[x] of the grid row at `base`. Neighbours mostly add to the same pair of
    cells (s pixels share a column cell, a smooth guide keeps the depth cell): the pair's sums
    stay in registers while the next pixel adds to the same pair and go to the grid when it
    changes."""
    key_open = -1  # 2 (xo + za) + (za == zb) of the open pair (zb = za at the clamped ends)
    at = at_z = 0
    s0 = s1 = s2 = s3 = t0 = t1 = t2 = t3 = _ZERO
    for x in range(pixels.shape[0]):
        p = pixels[x]
        zs = za[x]
        key = 2 * (xo[x] + zs) + (1 if zs == zb[x] else 0)
        if key != key_open:
            if key_open >= 0:
                _add(grid, at, s0, s1, s2, s3)
                _add(grid, at_z, t0, t1, t2, t3)
            key_open, at, at_z = key, base + xo[x] + zs, base + xo[x] + zb[x]
            s0 = s1 = s2 = s3 = t0 = t1 = t2 = t3 = _ZERO
        wxy = wy * wx[x]
        wa, wb = wxy * wza[x], wxy * wzb[x]
        s0 += wa * p[0]
        s1 += wa * p[1]
        s2 += wa * p[2]
        s3 += wa * p[3]
        t0 += wb * p[0]
        t1 += wb * p[1]
        t2 += wb * p[2]
        t3 += wb * p[3]
    if key_open >= 0:
        _add(grid, at, s0, s1, s2, s3)
        _add(grid, at_z, t0, t1, t2, t3)


@njit(parallel=True, cache=True, fastmath=True)
def _splat(hom, rows, y_lo, y_hi, x0, x1, wx0, wx1, z0, z1, wz0, wz1, grid, row_size):
    """Flat grid (N, Gh, Gw, D, CELL): each cell = [sum T image / sum T, sum T] over the pixels
    reaching it. One task per grid row (n, i), fed by the pixel rows y_lo[i] .. y_hi[i] - 1 with
    their weight for row i in rows[i, y] (no two tasks write one cell), each pixel row once
    for its first column cells and once for its second (`_splat_row`). Zero weights add zeros,
    as in the torch form. At 720p on nbg's guides, s = 4: 8.1 ms against 9.4-10.0 with a
    read-modify-write of the grid per pixel and corner; s = 8 and 16: the same time."""
    n_img = hom.shape[0]
    gh = rows.shape[0]
    cells = grid.reshape(grid.shape[0] // row_size, row_size // CELL, CELL)
    for task in prange(n_img * gh):
        n, i = task // gh, task % gh
        base = task * row_size
        grid[base : base + row_size] = 0.0
        for y in range(y_lo[i], y_hi[i]):
            wy = rows[i, y]
            if wy > 0.0:
                za, zb, wza, wzb = z0[n, y], z1[n, y], wz0[n, y], wz1[n, y]
                _splat_row(grid, base, hom[n, y], x0, wx0, wy, za, zb, wza, wzb)
                _splat_row(grid, base, hom[n, y], x1, wx1, wy, za, zb, wza, wzb)
        _normalise(cells[task])  # Meng20 eq. (10), the row still in cache


@njit(parallel=True, cache=True, fastmath=True)
def _slice(grid, row_size, y0, y1, wy0, wy1, x0, x1, wx0, wx1, z0, z1, wz0, wz1, c0, out):
    """out[n, c0 : c0 + 3, y, x] = sum T M / sum T over the pixel's 8 corners whose sum T is
    positive (Meng20 eq. (13)). Corner offsets are clamped into the grid; corners outside it
    have weight 0."""
    n_img, n_ch, h, w = out.shape
    gh = grid.shape[0] // (n_img * row_size)
    for task in prange(n_img * h):
        n, y = task // h, task % h
        at_a = (n * gh + y0[y]) * row_size
        at_b = (n * gh + y1[y]) * row_size
        wya, wyb = wy0[y], wy1[y]
        za, zb, wza, wzb = z0[n, y], z1[n, y], wz0[n, y], wz1[n, y]
        o0, o1, o2 = (
            out[n, c0, y],
            out[n, min(c0 + 1, n_ch - 1), y],
            out[n, min(c0 + 2, n_ch - 1), y],
        )
        for x in range(w):
            m0 = m1 = m2 = den = _ZERO
            for at_y, wy in ((at_a, wya), (at_b, wyb)):
                for xo, wx in ((x0[x], wx0[x]), (x1[x], wx1[x])):
                    wxy = wy * wx
                    for zo, wz in ((za[x], wza[x]), (zb[x], wzb[x])):
                        a = uintp(at_y + xo + zo)
                        wt = wxy * wz if grid[a + uintp(3)] > 0.0 else _ZERO
                        m0 += wt * grid[a]
                        m1 += wt * grid[a + uintp(1)]
                        m2 += wt * grid[a + uintp(2)]
                        den += wt
            inv = _ONE / den if den > 0.0 else _ZERO
            # channels past the last one (C not a multiple of 3) are written first, then
            # overwritten by the real ones: o2 / o1 alias the last channel
            o2[x] = m2 * inv
            o1[x] = m1 * inv
            o0[x] = m0 * inv


@lru_cache(maxsize=16)
def _plan(h: int, w: int, cell_size: int, grid_depth: int) -> tuple:
    """The tables that depend on the frame and grid sizes only, kept for the next frame (at
    320x240 building them took about a tenth of nbg's three grids): grid shape, row and column
    cells and weights (column cells as offsets within a grid row), and for the splat the weight
    of pixel row y for grid row i with the pixel rows reaching each grid row."""
    gh, gw, d = grid_shape(h, w, cell_size, grid_depth)
    y0, y1, wy0, wy1 = _axis_table(h, cell_size, gh)
    x0, x1, wx0, wx1 = _axis_table(w, cell_size, gw)
    x0, x1 = x0 * (d * CELL), x1 * (d * CELL)  # offsets within a grid row
    rows = np.zeros((gh, h), np.float32)
    rows[y0, np.arange(h)] += wy0
    rows[y1, np.arange(h)] += wy1
    reach = rows > 0
    y_lo = np.where(reach.any(1), reach.argmax(1), 0)
    y_hi = np.where(reach.any(1), h - reach[:, ::-1].argmax(1), 0)
    return (gh, gw, d), (y0, y1, wy0, wy1), (x0, x1, wx0, wx1), (rows, y_lo, y_hi)


@fast_kernel("BilateralGrid")
def bilateral_grid(
    image: np.ndarray, guide: np.ndarray, out: np.ndarray, cell_size: int, grid_depth: int
) -> None:
    """image (N, C, H, W), guide (N, 1, H, W) -> out (N, C, H, W)."""
    n, c, h, w = image.shape
    (gh, gw, d), (y0, y1, wy0, wy1), (x0, x1, wx0, wx1), (rows, y_lo, y_hi) = _plan(
        h, w, cell_size, grid_depth
    )
    row_size = gw * d * CELL  # floats per grid row
    z0 = np.empty((n, h, w), np.int32)
    z1 = np.empty((n, h, w), np.int32)
    wz0 = np.empty((n, h, w), np.float32)
    wz1 = np.empty((n, h, w), np.float32)
    hom = np.empty((n, h, w, CELL), np.float32)
    grid = np.empty(n * gh * row_size, np.float32)
    # the weights do not depend on the image: channels 3 at a time (the last group padded)
    for c0 in range(0, c, CELL - 1):
        _prepare(image, c0, guide, d, hom, z0, z1, wz0, wz1)
        _splat(hom, rows, y_lo, y_hi, x0, x1, wx0, wx1, z0, z1, wz0, wz1, grid, row_size)
        _slice(grid, row_size, y0, y1, wy0, wy1, x0, x1, wx0, wx1, z0, z1, wz0, wz1, c0, out)
