"""Synthetic frames for checks and benchmarks when no rendered sequence is at hand (numpy only)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .contract import BUFFER_CHANNELS


def synthetic_frames(
    inputs: Sequence[str], n: int, h: int, w: int, seed: int = 0
) -> list[dict[str, np.ndarray]]:
    """A moving sequence: smooth scene, noisy color (and color_b), 1 px pan per frame.

    Returns n dicts with the requested canonical buffers, (C, H, W) float32 each.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    frames = []
    for t in range(n):
        phase = xx + t
        albedo = np.stack([0.5 + 0.4 * np.sin(phase / 7 + c) for c in range(3)]).astype(np.float32)
        shading = (1.0 + np.cos(yy / 9)[None] * 0.5).astype(np.float32)
        noise = rng.exponential(1.0, size=(3, h, w)).astype(np.float32)
        buffers = {
            "color": albedo * shading * noise,
            "color_b": albedo * shading * rng.exponential(1.0, size=(3, h, w)).astype(np.float32),
            "albedo": albedo,
            "normal": np.stack([np.zeros_like(xx), np.zeros_like(xx), np.ones_like(xx)]),
            "depth": (5.0 + yy / h)[None].astype(np.float32),
            "motion": np.stack([np.ones_like(xx), np.zeros_like(xx)]).astype(np.float32),
        }
        frames.append({k: buffers[k] for k in inputs if k in BUFFER_CHANNELS})
    return frames
