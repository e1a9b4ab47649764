"""Random but plausible frame buffers for model tests (N, C, H, W torch tensors)."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def random_buffers(seed: int, n: int, h: int, w: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "color": torch.rand(n, 3, h, w, generator=g) * 4.0,
        "color_b": torch.rand(n, 3, h, w, generator=g) * 4.0,
        "albedo": torch.rand(n, 3, h, w, generator=g),
        "normal": F.normalize(torch.randn(n, 3, h, w, generator=g), dim=1),
        "depth": 1.0 + torch.rand(n, 1, h, w, generator=g) * 5.0,
        "motion": (torch.rand(n, 2, h, w, generator=g) - 0.5) * 3.0,
    }
