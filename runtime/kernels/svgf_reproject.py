"""SvgfReproject as a fast kernel; spec: rtdenoise.ops.svgf_reproject.

Two parallel passes over the rows: the first computes, per pixel, the fwidths, the four tested
bilinear taps and (with `fallback`) the 3 x 3 block around the rounded position, writing the
unmasked warp and the validity; the second erodes the validity (it reads the neighbouring
rows) and masks the warp. The float32 arithmetic is the torch form's, step by step and without
fastmath, so the forms agree to the bit: each tap's value is read at the clamped position and
added as its weight (0 for a failed tap) times the value, as the torch form's Where does.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .fast_kernel import fast_kernel


@njit(cache=True, inline="always")
def _clamped_index(f, size):
    """An integer-valued float position -> the clamped pixel index."""
    if not f > np.float32(0.0):
        return 0
    if f > np.float32(size - 1):
        return size - 1
    return int(f)


@njit(cache=True, inline="always")
def _tap_ok(geo, n, fx, fy, h, w, z, n0, n1, n2, depth_tol, normal_tol):
    """(flat index of the clamped tap, whether it passes) for an integer-valued position."""
    iy = _clamped_index(fy, h)
    ix = _clamped_index(fx, w)
    inside = (
        fx >= np.float32(0.0)
        and fx <= np.float32(w - 1)
        and fy >= np.float32(0.0)
        and fy <= np.float32(h - 1)
    )
    d0 = geo[n, 0, iy, ix] - n0
    d1 = geo[n, 1, iy, ix] - n1
    d2 = geo[n, 2, iy, ix] - n2
    dn = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    depth_ok = abs(geo[n, 3, iy, ix] - z) <= depth_tol
    return iy * w + ix, inside and depth_ok and dn <= normal_tol


@njit(parallel=True, cache=True)  # no fastmath: numba compiles the callees with these flags
def _warp_nb(previous, geo, motion, normal, depth, depth_thr, normal_thr, fallback, warped, valid):
    n_img, c, h, w = previous.shape
    eps, zero, one = np.float32(1e-2), np.float32(0.0), np.float32(1.0)
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        flat = previous[n].reshape(c, h * w)
        acc = np.empty(c, np.float32)
        yd = y + 1 if y < h - 1 else y  # forward differences; the last row repeats its
        yu = y if y < h - 1 else y - 1  # neighbour's
        for x in range(w):
            xr = x + 1 if x < w - 1 else x
            xl = x if x < w - 1 else x - 1
            z = depth[n, 0, y, x]
            dzx = abs(depth[n, 0, y, xr] - depth[n, 0, y, xl])
            dzy = abs(depth[n, 0, yd, x] - depth[n, 0, yu, x])
            fw_z = max(dzx, dzy)
            s0 = abs(normal[n, 0, y, xr] - normal[n, 0, y, xl]) + abs(
                normal[n, 0, yd, x] - normal[n, 0, yu, x]
            )
            s1 = abs(normal[n, 1, y, xr] - normal[n, 1, y, xl]) + abs(
                normal[n, 1, yd, x] - normal[n, 1, yu, x]
            )
            s2 = abs(normal[n, 2, y, xr] - normal[n, 2, y, xl]) + abs(
                normal[n, 2, yd, x] - normal[n, 2, yu, x]
            )
            fw_n = np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
            depth_tol = depth_thr * (fw_z + eps)
            normal_tol = normal_thr * (fw_n + eps)
            n0, n1, n2 = normal[n, 0, y, x], normal[n, 1, y, x], normal[n, 2, y, x]
            px = np.float32(x) + motion[n, 0, y, x]
            py = np.float32(y) + motion[n, 1, y, x]
            x0 = np.float32(np.floor(px))
            y0 = np.float32(np.floor(py))
            ax = px - x0
            ay = py - y0
            for k in range(c):
                acc[k] = zero
            total = zero
            for t in range(4):
                ox = t & 1
                oy = t >> 1
                wx = ax if ox else one - ax
                wy = ay if oy else one - ay
                wgt = wx * wy
                idx, ok = _tap_ok(
                    geo, n, x0 + np.float32(ox), y0 + np.float32(oy), h, w, z, n0, n1, n2,
                    depth_tol, normal_tol,
                )  # fmt: skip
                if not ok:
                    wgt = zero
                for k in range(c):
                    acc[k] = acc[k] + wgt * flat[k, idx]
                total = total + wgt
            ok_all = total >= eps
            for k in range(c):
                warped[n, k, y, x] = acc[k] / total if ok_all else zero
            if fallback and not ok_all:
                rx = np.float32(np.floor(px + np.float32(0.5)))
                ry = np.float32(np.floor(py + np.float32(0.5)))
                for k in range(c):
                    acc[k] = zero
                count = zero
                for oy in range(-1, 2):
                    for ox in range(-1, 2):
                        idx, ok = _tap_ok(
                            geo, n, rx + np.float32(ox), ry + np.float32(oy), h, w, z,
                            n0, n1, n2, depth_tol, normal_tol,
                        )  # fmt: skip
                        if ok:
                            for k in range(c):
                                acc[k] = acc[k] + flat[k, idx]
                            count = count + one
                if count > zero:
                    for k in range(c):
                        warped[n, k, y, x] = acc[k] / count
                    ok_all = True
            valid[n, 0, y, x] = one if ok_all else zero


@njit(parallel=True, cache=True)
def _erode_nb(unmasked, valid, erode, warped, mask):
    n_img, c, h, w = warped.shape
    for row in prange(n_img * h):
        n = row // h
        y = row - n * h
        for x in range(w):
            m = valid[n, 0, y, x]
            if erode:
                for yy in range(max(y - 1, 0), min(y + 2, h)):
                    for xx in range(max(x - 1, 0), min(x + 2, w)):
                        m = min(m, valid[n, 0, yy, xx])
            mask[n, 0, y, x] = m
            for k in range(c):
                warped[n, k, y, x] = unmasked[n, k, y, x] * m


@fast_kernel("SvgfReproject")
def svgf_reproject(
    previous: np.ndarray,
    prev_geometry: np.ndarray,
    motion: np.ndarray,
    normal: np.ndarray,
    depth: np.ndarray,
    depth_threshold: np.ndarray,
    normal_threshold: np.ndarray,
    warped: np.ndarray,
    valid: np.ndarray,
    fallback: int = 1,
    erode: int = 1,
) -> None:
    """previous (N, C, H, W), prev_geometry (N, 4, H, W), motion, normal, depth and the two
    thresholds -> warped * mask (N, C, H, W), mask (N, 1, H, W)."""
    unmasked = np.empty_like(warped)
    before = np.empty_like(valid)
    f32 = np.float32
    _warp_nb(
        previous, prev_geometry, motion, normal, depth, f32(depth_threshold),
        f32(normal_threshold), bool(fallback), unmasked, before,
    )  # fmt: skip
    _erode_nb(unmasked, before, bool(erode), warped, valid)
