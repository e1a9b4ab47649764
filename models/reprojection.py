"""SVGF-style reprojection (Schied17, as Choi24's official code does it): the op SvgfReproject.

Per pixel, the previous position is current + motion (pixels; docs/contract.md). Each of the
four bilinear taps around it is tested on its own against the current pixel:
- inside the previous frame;
- depth: |z_prev - z| / (fwidth_z + 1e-2) <= depth_threshold (fwidth_z: the larger of the
  horizontal and vertical depth differences at the current pixel);
- normal: ||n - n_prev|| / (fwidth_n + 1e-2) <= normal_threshold (fwidth_n: the length of
  |d n / dx| + |d n / dy|, HLSL's fwidth).
The accepted taps are renormalised by their bilinear weights; where they weigh less than 0.01,
an optional 3 x 3 fallback averages the accepted pixels around the rounded position (binary
weights). The validity mask is then eroded by a 3 x 3 minimum (bilinear taps near a rejected
region mix surfaces). One custom op (rtdenoise.ops.svgf_reproject; its torch form, the
reference in tensor ops, is models/ops/svgf_reproject.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .ops.svgf_reproject import fwidths, gather_pixels, svgf_reproject_reference


@dataclass(frozen=True)
class ReprojectionConfig:
    depth_threshold: float = 10.0  # Falcor SVGFReproject: |dz| / (fwidth_z + 1e-2) > 10 fails
    normal_threshold: float = 4.0  # ||dn|| / (fwidth_n + 1e-2) > 4 fails
    fallback: bool = True  # 3 x 3 binary fallback where the bilinear taps fail
    erode: bool = True  # 3 x 3 min of the validity mask


def svgf_reproject(
    previous: torch.Tensor,
    prev_normal: torch.Tensor,
    prev_depth: torch.Tensor,
    motion: torch.Tensor,
    normal: torch.Tensor,
    depth: torch.Tensor,
    config: ReprojectionConfig = ReprojectionConfig(),
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reproject `previous` (N, C, H, W) to the current pixels; returns (warped, valid), valid
    (N, 1, H, W) in {0, 1} and warped 0 where invalid. See the module docstring."""
    geometry = torch.cat((prev_normal, prev_depth), dim=1)
    return svgf_reproject_geometry(previous, geometry, motion, normal, depth, config)


def svgf_reproject_geometry(
    previous: torch.Tensor,
    prev_geometry: torch.Tensor,
    motion: torch.Tensor,
    normal: torch.Tensor,
    depth: torch.Tensor,
    config: ReprojectionConfig = ReprojectionConfig(),
) -> tuple[torch.Tensor, torch.Tensor]:
    """`svgf_reproject` with the previous normal and depth as one (N, 4, H, W) tensor (a
    family's geometry state): one SvgfReproject node."""
    scalar = lambda v: torch.tensor(v, dtype=previous.dtype, device=previous.device)  # noqa: E731
    return svgf_reproject_reference(
        previous,
        prev_geometry,
        motion,
        normal,
        depth,
        scalar(config.depth_threshold),
        scalar(config.normal_threshold),
        fallback=int(config.fallback),
        erode=int(config.erode),
    )


__all__ = [
    "ReprojectionConfig",
    "fwidths",
    "gather_pixels",
    "svgf_reproject",
    "svgf_reproject_geometry",
]
