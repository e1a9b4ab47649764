"""Synthetic frames for checks and benchmarks when no rendered sequence is at hand (numpy only)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..contract import SAMPLES
from .samples import DEFAULT_SAMPLE_FEATURES


def synthetic_frames(
    inputs: Sequence[str],
    n: int,
    h: int,
    w: int,
    seed: int = 0,
    sample_features: Sequence[str] = (),
    samples: int = 2,
) -> list[dict[str, np.ndarray]]:
    """A moving sequence: smooth scene, noisy color (and color_b), 1 px pan per frame.

    Returns n dicts with the requested canonical buffers, (C, H, W) float32 each; `samples`
    (when requested): (S, C, H, W), S = `samples` noisy samples of `sample_features` (the
    default set when empty) whose mean is `color`.
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
        if SAMPLES in inputs:
            colors = albedo * shading * rng.exponential(1.0, size=(samples, 3, h, w))
            buffers["color"] = colors.mean(axis=0).astype(np.float32)
            per_sample = [
                colors
                if f == "color"
                else np.broadcast_to(buffers[f], (samples, *buffers[f].shape))
                for f in sample_features or DEFAULT_SAMPLE_FEATURES
            ]
            buffers[SAMPLES] = np.concatenate(per_sample, axis=1).astype(np.float32)
        frames.append({k: buffers[k] for k in inputs if k in buffers})
    return frames
