"""Input conditioning shared by the families: sanitised buffers and scaled features."""

from __future__ import annotations

import torch


def frame_inputs(buffers: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """(color, albedo, normal, depth, motion) with radiance, albedo and depth clamped >= 0."""
    return (
        torch.clamp(buffers["color"], min=0.0),
        torch.clamp(buffers["albedo"], min=0.0),
        buffers["normal"],
        torch.clamp(buffers["depth"], min=0.0),
        buffers["motion"],
    )


def depth01(depth: torch.Tensor, mode: str) -> torch.Tensor:
    """Depth scaled to [0, 1] per frame (Lee24 III-A): "linear" d / max d, or "log"
    log1p(d) / log1p(max d), which keeps resolution on the foreground next to a far background."""
    if mode == "log":
        depth = torch.log1p(depth)
    return depth / (depth.amax(dim=(1, 2, 3), keepdim=True) + 1e-6)
