"""Training path of the affinity ops: numba forward and backward as torch autograd Functions.

The tensor-op references (models.ops.affinity_filter / temporal_affinity_filter) are the
numeric definition, but differentiating them costs ~170 tensor passes per kernel (a 13 x 13
kernel of 8-D features at a 64 x 64 crop took ~45 s of CPU per training step). Here the
forward is the fast kernel's row loops (runtime.kernels.affinity_filter) keeping 1 / den, and
the backward recomputes each tap's weight instead of storing it, in two gathers so that
every parallel iteration writes only its own row:

    out_p = num_p / den_p,  num_p = sum_q w_pq x_q,  den_p = 1e-10 + sum_q w_pq,
    w_pq = m_q exp(-a_p D_pq) (q != p), w_pp = c_p,  D_pq = ||f_p - g_q||^2
    H_p = G_p / den_p,  beta_p = H_p . out_p,  dw_pq = H_p . x_q - beta_p,
    coef_pq = dL/dD_pq = -a_p w_pq dw_pq

pass 1 (over p): dc_p = dw_pp, da_p += -w_pq dw_pq D_pq, df_p += 2 coef_pq (f_p - g_q);
pass 2 (over q): dx_q += w_pq H_p, dg_q += 2 coef_pq (g_q - f_p) (g = f for the spatial
kernel: both terms go to the features). The temporal kernel's mask gets no gradient.
`affinity_filter` / `temporal_affinity_filter` (the public functions) take this path when
autograd records on CPU; tests check its gradients against the references'.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from numba import njit, prange, uintp

from rtdenoise.ops.affinity_filter import EPS
from rtdenoise.runtime.kernels.affinity_filter import (
    affinity_taps,
    apply_mask,
    dist1,
    dist4,
    spatial_sums,
)
from rtdenoise.runtime.kernels.cache import clear_if_sources_changed, kernel_sources
from rtdenoise.runtime.kernels.common import exp_neg

from .export_mode import use_custom_op

# The functions below inline the kernels' row helpers: their cache goes with those sources too.
clear_if_sources_changed(Path(__file__).parent, [*kernel_sources(), Path(__file__)])
_EPS = np.float32(EPS)


# -- row helpers over x in [x0, x1) (unsigned indices: no wrap-around checks, they vectorise) ---


@njit(cache=True, fastmath=True)
def _distance(dist, feats, ya, offa, guides, yb, offb, x0, x1):
    """dist[x] = ||feats[:, ya, x + offa] - guides[:, yb, x + offb]||^2 (offa is 0 or -offb)."""
    n_feat = feats.shape[0]
    if offa == 0:
        y, yy, off = ya, yb, offb
        f, g = feats, guides
    else:  # swap the roles: the squared distance is symmetric
        y, yy, off = yb, ya, offa
        f, g = guides, feats
    for c in range(0, n_feat - n_feat % 4, 4):
        dist4(dist, f, g, c, y, yy, off, x0, x1, c == 0)
    for c in range(n_feat - n_feat % 4, n_feat):
        dist1(dist, f, g, c, y, yy, off, x0, x1, c == 0)


@njit(cache=True, fastmath=True)
def _weights_at(weight, dist, a, ya, offa, x0, x1):
    """weight[x] = exp(-a[ya, x + offa] * dist[x])."""
    for x in range(x0, x1):
        u = uintp(x)
        weight[u] = exp_neg(-a[ya, uintp(x + offa)] * dist[u])


@njit(cache=True, fastmath=True)
def _dw(dw, hh, yh, offh, values, yv, offv, beta, x0, x1):
    """dw[x] = sum_c hh[c, yh, x + offh] values[c, yv, x + offv] - beta[yh, x + offh]."""
    for x in range(x0, x1):
        dw[uintp(x)] = -beta[yh, uintp(x + offh)]
    for c in range(values.shape[0]):
        for x in range(x0, x1):
            u = uintp(x)
            dw[u] += hh[c, yh, uintp(x + offh)] * values[c, yv, uintp(x + offv)]


@njit(cache=True, fastmath=True)
def _p_coef(coef, g_a, dw, weight, dist, a, y, x0, x1):
    """t = dw w: g_a[y, x] -= t D; coef = 2 dL/dD = -2 a t (pass 1, p at row y)."""
    for x in range(x0, x1):
        u = uintp(x)
        t = dw[u] * weight[u]
        g_a[y, u] -= t * dist[u]
        coef[u] = np.float32(-2.0) * a[y, u] * t


@njit(cache=True, fastmath=True)
def _q_coef(coef, dw, weight, a, yp, offp, x0, x1):
    """coef = -2 a_p w dw with p at (yp, x + offp) (pass 2)."""
    for x in range(x0, x1):
        u = uintp(x)
        coef[u] = np.float32(-2.0) * a[yp, uintp(x + offp)] * dw[u] * weight[u]


@njit(cache=True, fastmath=True)
def _feature_grad(grad, coef, f, y, g, yg, offg, x0, x1):
    """grad[:, y, x] += coef[x] (f[:, y, x] - g[:, yg, x + offg])."""
    for c in range(f.shape[0]):
        for x in range(x0, x1):
            u = uintp(x)
            grad[c, y, u] += coef[u] * (f[c, y, u] - g[c, yg, uintp(x + offg)])


@njit(cache=True, fastmath=True)
def _value_grad(grad, weight, hh, y, yh, offh, x0, x1):
    """grad[:, y, x] += weight[x] hh[:, yh, x + offh]."""
    for c in range(grad.shape[0]):
        for x in range(x0, x1):
            u = uintp(x)
            grad[c, y, u] += weight[u] * hh[c, yh, uintp(x + offh)]


# -- the two gathers of one kernel ---------------------------------------------------------------


@njit(cache=True, fastmath=True)
def _pass_p(g_feats, g_a, hh, beta, feats, a, values, guides, mask, use_mask, skip_centre,
            y, k, d, dist, weight, dw, coef):  # fmt: skip
    """Pass 1 for output row y: the bandwidth and p-side feature gradients of every tap."""
    h, w = a.shape
    r = k // 2
    for i in range(k):
        yy = y + (i - r) * d
        if yy < 0 or yy >= h:
            continue
        for j in range(k):
            if skip_centre and i == r and j == r:
                continue
            off = (j - r) * d
            x0, x1 = max(0, -off), min(w, w - off)
            if x1 <= x0:
                continue
            _distance(dist, feats, y, 0, guides, yy, off, x0, x1)
            _weights_at(weight, dist, a, y, 0, x0, x1)
            if use_mask:
                apply_mask(weight, mask, yy, off, x0, x1)
            _dw(dw, hh, y, 0, values, yy, off, beta, x0, x1)
            _p_coef(coef, g_a, dw, weight, dist, a, y, x0, x1)
            _feature_grad(g_feats, coef, feats, y, guides, yy, off, x0, x1)


@njit(cache=True, fastmath=True)
def _pass_q(g_values, g_guides, hh, beta, feats, a, values, guides, mask, use_mask, skip_centre,
            y, k, d, dist, weight, dw, coef):  # fmt: skip
    """Pass 2 for row y as the neighbour q of p = q - offset: value and guide gradients."""
    h, w = a.shape
    r = k // 2
    for i in range(k):
        yp = y - (i - r) * d
        if yp < 0 or yp >= h:
            continue
        for j in range(k):
            if skip_centre and i == r and j == r:
                continue
            off = (j - r) * d  # q = p + off, so p = x - off
            x0, x1 = max(0, off), min(w, w + off)
            if x1 <= x0:
                continue
            _distance(dist, feats, yp, -off, guides, y, 0, x0, x1)
            _weights_at(weight, dist, a, yp, -off, x0, x1)
            if use_mask:
                apply_mask(weight, mask, y, 0, x0, x1)
            _value_grad(g_values, weight, hh, y, yp, -off, x0, x1)
            _dw(dw, hh, yp, -off, values, y, 0, beta, x0, x1)
            _q_coef(coef, dw, weight, a, yp, -off, x0, x1)
            _feature_grad(g_guides, coef, guides, y, feats, yp, -off, x0, x1)


# -- drivers ----------------------------------------------------------------------------------


@njit(parallel=True, cache=True, fastmath=True)
def _forward_nb(image, features, bandwidth, centre, previous, prev_features, t_bandwidth,
                valid, k, kt, d, temporal, out, inv_den):  # fmt: skip
    """out (and 1 / den) of AffinityFilter, or of TemporalAffinityFilter when `temporal`."""
    n_img, n_ch, h, w = image.shape
    no_mask = np.zeros((1, 1), dtype=np.float32)
    for row in prange(n_img * h):
        u = np.int64(row)
        n, y = u // h, u % h
        num, den, dist, weight = spatial_sums(
            image, features, bandwidth, centre, no_mask, n, y, 0, w, k, d
        )
        if temporal:
            affinity_taps(
                num, den, features[n], t_bandwidth[n, 0, y], previous[n], prev_features[n],
                valid[n, 0], y, 0, w, kt, 1, False, True, dist, weight,
            )  # fmt: skip
        for x in range(w):
            inv_den[n, y, x] = np.float32(1.0) / (_EPS + den[x])
        for c in range(n_ch):
            for x in range(w):
                out[n, c, y, x] = num[c, x] * inv_den[n, y, x]


@njit(parallel=True, cache=True, fastmath=True)
def _backward_nb(grad_out, out, inv_den, image, features, bandwidth, centre, previous,
                 prev_features, t_bandwidth, valid, k, kt, d, temporal, g_image, g_features,
                 g_bandwidth, g_centre, g_previous, g_prev_features, g_t_bandwidth):  # fmt: skip
    """Gradients of the inputs (zero-filled outputs, accumulated here)."""
    n_img, n_ch, h, w = image.shape
    no_mask = np.zeros((1, 1), dtype=np.float32)
    hh = np.empty_like(grad_out)
    beta = np.empty((n_img, h, w), dtype=np.float32)
    for row in prange(n_img * h):  # H = G / den, beta = H . out
        u = np.int64(row)
        n, y = u // h, u % h
        for x in range(w):
            beta[n, y, x] = 0.0
        for c in range(n_ch):
            for x in range(w):
                v = grad_out[n, c, y, x] * inv_den[n, y, x]
                hh[n, c, y, x] = v
                beta[n, y, x] += v * out[n, c, y, x]
    for row in prange(n_img * h):  # pass 1: p-side
        u = np.int64(row)
        n, y = u // h, u % h
        dist, weight = np.empty(w, np.float32), np.empty(w, np.float32)
        dw, coef = np.empty(w, np.float32), np.empty(w, np.float32)
        for x in range(w):  # the centre weight: dc_p = dw_pp = H_p . x_p - beta_p
            s = -beta[n, y, x]
            for c in range(n_ch):
                s += hh[n, c, y, x] * image[n, c, y, x]
            g_centre[n, 0, y, x] = s
        _pass_p(
            g_features[n],
            g_bandwidth[n, 0],
            hh[n],
            beta[n],
            features[n],
            bandwidth[n, 0],
            image[n],
            features[n],
            no_mask,
            False,
            True,
            y,
            k,
            d,
            dist,
            weight,
            dw,
            coef,
        )
        if temporal:
            _pass_p(
                g_features[n], g_t_bandwidth[n, 0], hh[n], beta[n], features[n],
                t_bandwidth[n, 0], previous[n], prev_features[n], valid[n, 0], True, False,
                y, kt, 1, dist, weight, dw, coef,
            )  # fmt: skip
    for row in prange(n_img * h):  # pass 2: q-side
        u = np.int64(row)
        n, y = u // h, u % h
        dist, weight = np.empty(w, np.float32), np.empty(w, np.float32)
        dw, coef = np.empty(w, np.float32), np.empty(w, np.float32)
        for c in range(n_ch):  # the centre tap: dx_p += c_p H_p
            for x in range(w):
                g_image[n, c, y, x] += centre[n, 0, y, x] * hh[n, c, y, x]
        _pass_q(
            g_image[n],
            g_features[n],
            hh[n],
            beta[n],
            features[n],
            bandwidth[n, 0],
            image[n],
            features[n],
            no_mask,
            False,
            True,
            y,
            k,
            d,
            dist,
            weight,
            dw,
            coef,
        )
        if temporal:
            _pass_q(
                g_previous[n], g_prev_features[n], hh[n], beta[n], features[n],
                t_bandwidth[n, 0], previous[n], prev_features[n], valid[n, 0], True, False,
                y, kt, 1, dist, weight, dw, coef,
            )  # fmt: skip


# -- torch autograd Functions ---------------------------------------------------------------------


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy(), dtype=np.float32)


_NONE = np.zeros((1, 1, 1, 1), np.float32)


def _forward(inputs: list[np.ndarray], k: int, kt: int, d: int, temporal: bool):
    image = inputs[0]
    out = np.empty_like(image)
    inv_den = np.empty((image.shape[0], *image.shape[2:]), np.float32)
    extra = inputs[4:8] if temporal else [_NONE] * 4
    _forward_nb(*inputs[:4], *extra, k, kt, d, temporal, out, inv_den)
    return out, inv_den


def _backward(grad, out, inv_den, inputs, k, kt, d, temporal):
    grads = [np.zeros_like(x) for x in (inputs if temporal else inputs[:4])]
    extra = inputs[4:8] if temporal else [_NONE] * 4
    g_extra = [grads[4], grads[5], grads[6]] if temporal else [_NONE] * 3
    _backward_nb(
        _np(grad), out, inv_den, *inputs[:4], *extra, k, kt, d, temporal, *grads[:4], *g_extra
    )
    return grads


class AffinityFilterFunction(torch.autograd.Function):
    """AffinityFilter (Isik21 eq. (4), (6)) with the numba forward and backward."""

    @staticmethod
    def forward(ctx, image, features, bandwidth, centre, k: int, d: int):
        inputs = [_np(t) for t in (image, features, bandwidth, centre)]
        out, inv_den = _forward(inputs, k, 1, d, False)
        ctx.saved = (inputs, out, inv_den, k, d)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        inputs, out, inv_den, k, d = ctx.saved
        grads = _backward(grad, out, inv_den, inputs, k, 1, d, False)
        return (*(torch.from_numpy(g) for g in grads), None, None)


class TemporalAffinityFilterFunction(torch.autograd.Function):
    """TemporalAffinityFilter (Isik21 eq. (7)-(8)) with the numba forward and backward; the
    validity mask gets no gradient."""

    @staticmethod
    def forward(ctx, *args):
        tensors, (k, kt, d) = args[:8], args[8:]
        inputs = [_np(t) for t in tensors]
        out, inv_den = _forward(inputs, k, kt, d, True)
        ctx.saved = (inputs, out, inv_den, k, kt, d)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        inputs, out, inv_den, k, kt, d = ctx.saved
        grads = _backward(grad, out, inv_den, inputs, k, kt, d, True)
        return (*(torch.from_numpy(g) for g in grads[:7]), None, None, None, None)


def use_training_kernels(*tensors: torch.Tensor) -> bool:
    """True when autograd records a call on CPU float32 tensors outside an export: the
    public op functions then run these Functions instead of the tensor-op references."""
    return (
        torch.is_grad_enabled()
        and not use_custom_op()
        and any(t.requires_grad for t in tensors)
        and all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)
    )
