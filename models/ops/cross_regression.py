"""CrossRegression in torch form (Choi24 s.4.1, eqs. (4)-(7)); the op is defined in
rtdenoise.ops.cross_regression. Forward only: the pilots are inputs of the network and labels of
its loss, never differentiated. Computed in float64, returned in float32.

Both regressions run as one batch: A's variables against y^B stacked with B's against y^A.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rtdenoise.ops.cross_regression import reconstruction_offsets

from ._mirror import mirror_pad
from .torch_op import torch_op

P = 6  # regression variables per colour channel: 1, dy, d albedo, d normal xyz
# Per-pixel stack the regression reads: y (3), albedo (3), normal (3), sigma, var, target (3).
_Y, _ALB, _NRM, _STD, _VAR, _TGT = slice(0, 3), slice(3, 6), slice(6, 9), 9, 10, slice(11, 14)


def neighbour_variance(y: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) -> (B, 1, H, W): ||y_p - mean of the in-image 3x3 neighbours of p||^2."""
    h, w = y.shape[-2:]
    ones = torch.ones_like(y[:, :1])
    yp, op = F.pad(y, (1, 1, 1, 1)), F.pad(ones, (1, 1, 1, 1))
    total = sum(yp[..., i : i + h, j : j + w] for i in range(3) for j in range(3))
    count = sum(op[..., i : i + h, j : j + w] for i in range(3) for j in range(3))
    mean = (total - y) / (count - 1.0)
    return ((y - mean) ** 2).sum(dim=1, keepdim=True)


def variables(q: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Regression variables x(q; c) (B, 3, ..., 6) and weights w(c, q) (B, 1, ...) of pixels q
    relative to centres c, both given as the per-pixel stack (B, 14, ...). Choi24 eqs. (6)-(7)."""
    d = q - c
    dy = d[:, _Y]
    scale = c[:, _STD : _STD + 1] + q[:, _STD : _STD + 1] + 1e-2
    spread = c[:, _VAR : _VAR + 1] + q[:, _VAR : _VAR + 1] + 1e-4
    w = torch.exp(-(dy * dy).sum(dim=1, keepdim=True) / spread) + 1e-7
    x1, x2, dn = dy / scale, d[:, _ALB], d[:, _NRM]
    shared = [torch.ones_like(x1)] + [dn[:, k : k + 1].expand_as(x1) for k in range(3)]
    x = torch.stack((shared[0], x1, x2, *shared[1:]), dim=-1)
    return x, w


def regression_pilots(
    y: torch.Tensor,
    target: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    window: int,
    stride: int,
) -> torch.Tensor:
    """Fit `target` on the variables of `y` at the centres and reconstruct every pixel."""
    b, _, h, w = y.shape
    r = window // 2
    var = neighbour_variance(y)
    q = torch.cat((y, albedo, normal, var.sqrt(), var, target), dim=1)
    centres = q[..., ::stride, ::stride]  # (B, 14, Hc, Wc)
    hc, wc = centres.shape[-2:]
    padded = mirror_pad(q, r)

    # Normal equations (eq. (4)), accumulated one window row at a time.
    a = q.new_zeros(b, 3, hc, wc, P, P)
    rhs = q.new_zeros(b, 3, hc, wc, P)
    for dy in range(window):
        rows = padded[:, :, dy : dy + stride * (hc - 1) + 1 : stride]  # (B, 14, Hc, W + 2r)
        win = rows.unfold(3, window, stride)  # (B, 14, Hc, Wc, window)
        x, wgt = variables(win, centres.unsqueeze(-1))
        xw = x * wgt.unsqueeze(-1)
        a = a + xw.transpose(-1, -2) @ x
        rhs = rhs + (xw * win[:, _TGT].unsqueeze(-1)).sum(dim=-2)
    a = a + 1e-3 * torch.eye(P, dtype=a.dtype, device=a.device)
    beta = torch.cholesky_solve(rhs.unsqueeze(-1), torch.linalg.cholesky(a)).squeeze(-1)

    # Reconstruction (eq. (5)) from every centre whose window covers the pixel.
    grid = torch.cat((beta.permute(0, 1, 4, 2, 3).reshape(b, 3 * P, hc, wc), centres), dim=1)
    ys = torch.arange(h, device=y.device)
    xs = torch.arange(w, device=y.device)
    num = q.new_zeros(b, 3, h, w)
    den = q.new_zeros(b, 1, h, w)
    for dj in reconstruction_offsets(window, stride):
        j = ys // stride + dj
        vy = ((ys - stride * j).abs() <= r) & (j >= 0) & (j < hc)
        rows = grid.index_select(2, j.clamp(0, hc - 1))
        for di in reconstruction_offsets(window, stride):
            i = xs // stride + di
            vx = ((xs - stride * i).abs() <= r) & (i >= 0) & (i < wc)
            g = rows.index_select(3, i.clamp(0, wc - 1))  # (B, 18 + 14, H, W)
            x, wgt = variables(q, g[:, 3 * P :])
            coef = g[:, : 3 * P].reshape(b, 3, P, h, w).permute(0, 1, 3, 4, 2)
            wgt = wgt * (vy[:, None] & vx[None, :]).to(wgt.dtype)
            num = num + wgt * (x * coef).sum(dim=-1)
            den = den + wgt
    return torch.clamp(num / den, min=0.0)


@torch_op("CrossRegression")
def cross_regression_reference(
    y_a: torch.Tensor,
    y_b: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    window: int,
    stride: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(pilot_a, pilot_b), Choi24 eqs. (4)-(7); see rtdenoise.ops.cross_regression."""
    n = y_a.shape[0]
    y = torch.cat((y_a, y_b)).double()
    target = torch.cat((y_b, y_a)).double()
    albedo2 = torch.cat((albedo, albedo)).double()
    normal2 = torch.cat((normal, normal)).double()
    with torch.no_grad():
        pilots = regression_pilots(y, target, albedo2, normal2, window, stride).float()
    return pilots[:n].clone(), pilots[n:].clone()  # separate storage: custom-op outputs


def cross_regression(
    y_a: torch.Tensor,
    y_b: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    window: int = 17,
    stride: int = 4,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Choi24 cross-regression pilots (pilot_a from A's variables, pilot_b from B's) of the
    (N, 3, H, W) buffers (the model passes log1p radiance)."""
    return cross_regression_reference(y_a, y_b, albedo, normal, window=window, stride=stride)
