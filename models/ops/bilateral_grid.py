"""BilateralGrid in torch form (Meng20); defined in rtdenoise.ops.bilateral_grid.

Differentiable w.r.t. image and guide (the guide moves the tent weights; the cell indices are
piecewise constant), so GuideNet trains end to end through splat and slice. Splat is one
`scatter_add` of the 8 corner contributions [T * image, T] into a flat (N, C + 1, Gh*Gw*D)
grid; slice is one `gather` of the same 8 corners.
"""

from __future__ import annotations

import torch

from rtdenoise.ops.bilateral_grid import GUIDE_MAX, GUIDE_RANGE, TENT_EPS, grid_shape

from .torch_op import torch_op


def tent(u: torch.Tensor) -> torch.Tensor:
    """T(u) = max(1 - sqrt(u^2 + eps), 0) (Meng20 eq. (9) with the smoothed |u|)."""
    return torch.clamp(1.0 - torch.sqrt(u * u + TENT_EPS), min=0.0)


def _corners(p: torch.Tensor, cells: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The two cells around position p (in cell units, centres at k + 0.5) on one axis:
    [(index clamped into the grid, tent weight, 0 for a cell outside the grid)] x 2."""
    t = p - 0.5
    first = torch.floor(t)
    u = t - first
    i0 = first.long()
    out = []
    for k, uk in ((0, u), (1, u - 1.0)):
        i = i0 + k
        inside = (i >= 0) & (i < cells)
        out.append((i.clamp(0, cells - 1), tent(uk) * inside.to(p.dtype)))
    return out


@torch_op("BilateralGrid")
def bilateral_grid_reference(
    image: torch.Tensor, guide: torch.Tensor, cell_size: int, grid_depth: int
) -> torch.Tensor:
    """Differentiable tensor-op form (the numeric reference)."""
    n, c, h, w = image.shape
    gh, gw, d = grid_shape(h, w, cell_size, grid_depth)
    dtype = image.dtype
    ys = (torch.arange(h, dtype=dtype, device=image.device) + 0.5) / cell_size
    xs = (torch.arange(w, dtype=dtype, device=image.device) + 0.5) / cell_size
    zs = (torch.clamp(guide, 0.0, GUIDE_MAX) + 0.5) * d / GUIDE_RANGE  # Meng20 eq. (12)
    rows = _corners(ys.view(h, 1), gh)
    cols = _corners(xs.view(1, w), gw)
    depths = _corners(zs[:, 0], d)  # (N, H, W)
    index, weight = [], []
    for iy, wy in rows:
        for ix, wx in cols:
            for iz, wz in depths:
                index.append(((iy * gw + ix) * d + iz).expand(n, h, w))
                weight.append(wy * wx * wz)
    idx = torch.stack(index, 1).reshape(n, 1, 8 * h * w)  # (N, 1, 8 HW): corner-major
    wts = torch.stack(weight, 1).reshape(n, 1, 8, h * w)

    # Splat (Meng20 eqs. (10)-(11)): sums of T * image and of T per cell, then their ratio.
    src = torch.cat((image.reshape(n, c, 1, h * w) * wts, wts), 1).reshape(n, c + 1, 8 * h * w)
    sums = src.new_zeros(n, c + 1, gh * gw * d).scatter_add(2, idx.expand(n, c + 1, -1), src)
    total = sums[:, c:]
    filled = total > 0
    mean = torch.where(filled, sums[:, :c] / torch.where(filled, total, 1.0), 0.0)

    # Slice (Meng20 eq. (13)): the same corners and weights, over non-empty cells only.
    cells = torch.cat((mean, filled.to(dtype)), 1)
    read = torch.gather(cells, 2, idx.expand(n, c + 1, -1)).reshape(n, c + 1, 8, h * w)
    wm = wts * read[:, c:]
    num = (wm * read[:, :c]).sum(2)
    den = wm.sum(2)
    ok = den > 0
    out = torch.where(ok, num / torch.where(ok, den, 1.0), 0.0)
    return out.reshape(n, c, h, w)


def bilateral_grid(
    image: torch.Tensor, guide: torch.Tensor, cell_size: int, grid_depth: int
) -> torch.Tensor:
    """Denoise image (N, C, H, W) through a ceil(H/s) x ceil(W/s) x D bilateral grid placed by
    guide (N, 1, H, W) in [0, 255] (Meng20 eqs. (8)-(13))."""
    return bilateral_grid_reference(image, guide, cell_size=cell_size, grid_depth=grid_depth)
