"""Mirrored (reflecting) padding of any width, shared by the Choi24 ops' torch forms."""

from __future__ import annotations

import torch


def mirror_index(n: int, r: int, device: torch.device | None = None) -> torch.Tensor:
    """Indices of positions -r .. n - 1 + r reflected into [0, n) without repeating the edge
    (period 2 (n - 1), so any r works for n >= 2): -1 -> 1, n -> n - 2."""
    idx = torch.arange(-r, n + r, device=device)
    period = 2 * (n - 1)
    a = idx.abs() % period
    return torch.where(a >= n, period - a, a)


def mirror_pad(x: torch.Tensor, r: int) -> torch.Tensor:
    """(..., H, W) -> (..., H + 2r, W + 2r), reflected at the borders (`mirror_index`)."""
    h, w = x.shape[-2:]
    x = x.index_select(-2, mirror_index(h, r, x.device))
    return x.index_select(-1, mirror_index(w, r, x.device))
