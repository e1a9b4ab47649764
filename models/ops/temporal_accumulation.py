"""TemporalAccumulation in torch form (one TA step, `models.temporal`); the op is defined in
rtdenoise.ops.temporal_accumulation."""

from __future__ import annotations

import torch

from ..temporal import TemporalConfig, temporal_step
from .torch_op import torch_op


@torch_op("TemporalAccumulation")
def temporal_accumulation_reference(
    current: torch.Tensor,
    motion: torch.Tensor,
    depth: torch.Tensor,
    normal: torch.Tensor,
    ta_state: torch.Tensor,
    geometry_state: torch.Tensor,
    reset: torch.Tensor,
    depth_tolerance: torch.Tensor,
    normal_threshold: torch.Tensor,
    min_alpha: torch.Tensor,
    max_history: torch.Tensor,
    per_tap: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Differentiable tensor-op form (the numeric reference): `models.temporal.temporal_step`
    with the config's numbers as 0-d tensors and per_tap (0 bilinear, 1 per tap, 2 per tap
    HDR-weighted) as an int."""
    config = TemporalConfig(depth_tolerance, normal_threshold, min_alpha, max_history, per_tap)
    return temporal_step(current, motion, depth, normal, ta_state, geometry_state, reset, config)


def temporal_accumulation(
    current: torch.Tensor,
    motion: torch.Tensor,
    depth: torch.Tensor,
    normal: torch.Tensor,
    ta_state: torch.Tensor,
    geometry_state: torch.Tensor,
    reset: torch.Tensor,
    config: TemporalConfig | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One TA step on C-channel `current` (N, C, H, W) as the op TemporalAccumulation.

    ta_state: (N, C + 1, H, W) previous accumulation and its history length;
    geometry_state: (N, 4, H, W) previous normal (3) and depth (1); reset: 0-d, 1 drops the
    history. Returns (accumulated (N, C, H, W), blend weight a (N, 1, H, W), next ta_state,
    next geometry_state). `config`: TemporalConfig() by default; its per_tap becomes the
    node's attribute.
    """
    config = config or TemporalConfig()
    numbers = (config.depth_tolerance, config.normal_threshold, config.min_alpha)
    scalars = [current.new_tensor(v) for v in (*numbers, config.max_history)]
    return temporal_accumulation_reference(
        current,
        motion,
        depth,
        normal,
        ta_state,
        geometry_state,
        reset,
        *scalars,
        per_tap=int(config.per_tap),
    )
