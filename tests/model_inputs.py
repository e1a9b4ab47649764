"""Random but plausible frame buffers for model tests (N, C, H, W torch tensors)."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from rtdenoise.runtime.sequences.samples import DEFAULT_SAMPLE_FEATURES


def samples_of(buffers: dict[str, torch.Tensor], s: int = 2) -> torch.Tensor:
    """(N, S, C, H, W) per-sample buffers (the default features) whose colour mean is `color`:
    sample i scales the colour by a fixed factor, the factors averaging 1."""
    scales = torch.linspace(0.5, 1.5, s) if s > 1 else torch.ones(1)
    parts = []
    for name in DEFAULT_SAMPLE_FEATURES:
        x = buffers[name].unsqueeze(1).expand(-1, s, -1, -1, -1)
        parts.append(x * scales.view(1, s, 1, 1, 1) if name == "color" else x)
    return torch.cat(parts, dim=2).contiguous()


def random_buffers(seed: int, n: int, h: int, w: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    buffers = {
        "color": torch.rand(n, 3, h, w, generator=g) * 4.0,
        "color_b": torch.rand(n, 3, h, w, generator=g) * 4.0,
        "albedo": torch.rand(n, 3, h, w, generator=g),
        "normal": F.normalize(torch.randn(n, 3, h, w, generator=g), dim=1),
        "depth": 1.0 + torch.rand(n, 1, h, w, generator=g) * 5.0,
        "motion": (torch.rand(n, 2, h, w, generator=g) - 0.5) * 3.0,
    }
    return buffers | {"samples": samples_of(buffers)}


def conv_macs_per_pixel(model: torch.nn.Module, h: int = 32, w: int = 32) -> float:
    """Multiply-adds of every Conv2d of a frame-buffer model per pixel, counted by forward
    hooks on one (h, w) frame of random buffers."""
    macs = []

    def hook(conv, inputs, output):
        k = conv.kernel_size[0] * conv.kernel_size[1] * conv.in_channels // conv.groups
        macs.append(output.numel() * k)

    convs = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
    handles = [m.register_forward_hook(hook) for m in convs]
    buffers = {k: v for k, v in random_buffers(0, 1, h, w).items() if k in model.inputs}
    with torch.no_grad():
        model(buffers, model.initial_state(1, h, w), torch.tensor(1.0))
    for handle in handles:
        handle.remove()
    return sum(macs) / (h * w)
