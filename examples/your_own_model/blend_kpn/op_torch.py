"""NeighbourBlend in torch form: the differentiable reference (blend_kpn.op_spec)."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rtdenoise.models.ops import torch_op

from . import op_spec  # noqa: F401  (the spec, before its form)


@torch_op("NeighbourBlend")
def neighbour_blend(image: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """image (N, C, H, W) blended towards its 3 x 3 mean by weight (N, 1, H, W)."""
    box = F.avg_pool2d(F.pad(image, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
    return image + weight * (box - image)
