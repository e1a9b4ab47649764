"""SvgfReproject in torch form; the op is defined in rtdenoise.ops.svgf_reproject.

The differentiable reference in standard tensor ops (gathers, comparisons, Where, a max pool):
the spelling crossreg exported before the op existed, so its arithmetic (each float32 product
and sum in this order, no fused multiply-adds) is what the function body, the numba kernel and
the C++ kernel repeat.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .torch_op import torch_op


def _diff_x(x: torch.Tensor) -> torch.Tensor:
    """|x(y, x+1) - x(y, x)|, the last column repeating its neighbour's difference."""
    d = (x[..., :, 1:] - x[..., :, :-1]).abs()
    return torch.cat((d, d[..., :, -1:]), dim=-1)


def _diff_y(x: torch.Tensor) -> torch.Tensor:
    d = (x[..., 1:, :] - x[..., :-1, :]).abs()
    return torch.cat((d, d[..., -1:, :]), dim=-2)


def fwidths(depth: torch.Tensor, normal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(fwidth_z, fwidth_n), (N, 1, H, W) each: screen-space derivatives of depth and normal."""
    fw_z = torch.maximum(_diff_x(depth), _diff_y(depth))
    fw_n = torch.sqrt(((_diff_x(normal) + _diff_y(normal)) ** 2).sum(dim=1, keepdim=True))
    return fw_z, fw_n


def gather_pixels(flat: torch.Tensor, ix: torch.Tensor, iy: torch.Tensor, w: int) -> torch.Tensor:
    """flat (N, C, H*W) read at integer positions (ix, iy) (N, H, W), clamped -> (N, C, H, W)."""
    n, c, hw = flat.shape
    h = hw // w
    idx = iy.clamp(0, h - 1) * w + ix.clamp(0, w - 1)
    picked = torch.gather(flat, 2, idx.reshape(n, 1, -1).expand(n, c, idx[0].numel()))
    return picked.reshape(n, c, ix.shape[1], ix.shape[2])


@torch_op("SvgfReproject")
def svgf_reproject_reference(
    previous: torch.Tensor,
    prev_geometry: torch.Tensor,
    motion: torch.Tensor,
    normal: torch.Tensor,
    depth: torch.Tensor,
    depth_threshold: torch.Tensor,
    normal_threshold: torch.Tensor,
    fallback: int,
    erode: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(warped * mask, mask); see rtdenoise.ops.svgf_reproject."""
    n, c, h, w = previous.shape
    flat = torch.cat((previous, prev_geometry), dim=1).flatten(2)
    fw_z, fw_n = fwidths(depth, normal)
    depth_tol = depth_threshold * (fw_z + 1e-2)
    normal_tol = normal_threshold * (fw_n + 1e-2)
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype).view(1, 1, w)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype).view(1, h, 1)
    px, py = xs + motion[:, 0], ys + motion[:, 1]

    def tap(fx: torch.Tensor, fy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Values (N, C, H, W) at integer float positions and whether the tap passes."""
        g = gather_pixels(flat, fx.long(), fy.long(), w)
        inside = (fx >= 0) & (fx <= w - 1) & (fy >= 0) & (fy <= h - 1)
        depth_ok = (g[:, c + 3 : c + 4] - depth).abs() <= depth_tol
        dn = torch.sqrt(((g[:, c : c + 3] - normal) ** 2).sum(dim=1, keepdim=True))
        return g[:, :c], inside.unsqueeze(1) & depth_ok & (dn <= normal_tol)

    # Bilinear taps, each tested, renormalised (SVGF).
    x0, y0 = torch.floor(px), torch.floor(py)
    ax, ay = (px - x0).unsqueeze(1), (py - y0).unsqueeze(1)
    acc = previous.new_zeros(n, c, h, w)
    total = previous.new_zeros(n, 1, h, w)
    for ox, oy, wgt in (
        (0, 0, (1 - ax) * (1 - ay)),
        (1, 0, ax * (1 - ay)),
        (0, 1, (1 - ax) * ay),
        (1, 1, ax * ay),
    ):
        value, ok = tap(x0 + ox, y0 + oy)
        wgt = torch.where(ok, wgt, torch.zeros_like(wgt))
        acc = acc + wgt * value
        total = total + wgt
    valid = total >= 0.01
    warped = torch.where(valid, acc / torch.where(valid, total, torch.ones_like(total)), 0.0)

    if fallback:  # 3 x 3 binary cross-bilateral fallback around the rounded position
        rx, ry = torch.floor(px + 0.5), torch.floor(py + 0.5)
        fsum = previous.new_zeros(n, c, h, w)
        count = previous.new_zeros(n, 1, h, w)
        for oy in (-1, 0, 1):
            for ox in (-1, 0, 1):
                value, ok = tap(rx + ox, ry + oy)
                fsum = fsum + torch.where(ok, value, 0.0)
                count = count + ok.to(count.dtype)
        use = (~valid) & (count > 0)
        warped = torch.where(use, fsum / count.clamp(min=1.0), warped)
        valid = valid | use

    mask = valid.to(previous.dtype)
    if erode:  # 3 x 3 minimum, out-of-image neighbours ignored
        mask = -F.max_pool2d(-F.pad(mask, (1, 1, 1, 1), value=1.0), 3, stride=1)
    return warped * mask, mask
