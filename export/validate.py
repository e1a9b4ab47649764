"""Validation of an exported model: PyTorch vs ONNX Runtime (fast and portable) frame by frame.

Both sides run the same sequence with their own state fed back, so any drift in
the temporal path accumulates and shows. The error of a frame is
max |ort - torch| / (1 + |torch|): relative for bright HDR values, absolute near 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from rtdenoise.models.base import DenoiserModel
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.samples import DEFAULT_SAMPLE_FEATURES


@dataclass
class ValidationReport:
    """Per-frame errors of each ORT path against PyTorch."""

    tolerance: float
    errors: dict[str, list[float]] = field(default_factory=dict)

    @property
    def max_error(self) -> float:
        return max((max(v) for v in self.errors.values() if v), default=0.0)

    @property
    def passed(self) -> bool:
        return self.max_error <= self.tolerance


def frame_error(ort: np.ndarray, ref: np.ndarray) -> float:
    return float(np.max(np.abs(ort - ref) / (1.0 + np.abs(ref))))


def torch_outputs(
    model: DenoiserModel, frames: Sequence[dict[str, np.ndarray]]
) -> list[np.ndarray]:
    """Run the PyTorch model over frames (C,H,W arrays) with state fed back; outputs (3,H,W)."""
    with torch.no_grad():
        return [out[0].numpy() for out in FrameLoop(model).run(frames)]


def validate(
    model: DenoiserModel,
    onnx_bytes: bytes,
    frames: Sequence[dict[str, np.ndarray]],
    *,
    tolerance: float = 1e-4,
) -> ValidationReport:
    """Compare PyTorch with ORT-fast and ORT-portable over `frames`."""
    reference = torch_outputs(model.eval(), frames)
    report = ValidationReport(tolerance=tolerance)
    for path, fast in (("ort_fast", True), ("ort_portable", False)):
        denoiser = Denoiser(onnx_bytes, fast_kernels=fast)
        report.errors[path] = [
            frame_error(denoiser.process(frame), ref)
            for frame, ref in zip(frames, reference, strict=True)
        ]
    return report


def synthetic_frames(
    inputs: Sequence[str],
    n: int,
    h: int,
    w: int,
    seed: int = 0,
    sample_features: Sequence[str] = DEFAULT_SAMPLE_FEATURES,
    samples: int = 2,
) -> list[dict[str, np.ndarray]]:
    """A moving sequence for when no real one is at hand: smooth scene, noisy color, 1 px pan.

    `samples` (when listed in `inputs`): S = `samples` noisy samples of the features
    `sample_features` (whose mean is `color`)."""
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
            noise_s = rng.exponential(1.0, size=(samples, 3, h, w)).astype(np.float32)
            colors = albedo * shading * noise_s
            buffers["color"] = colors.mean(axis=0)
            per_sample = [
                colors
                if f == "color"
                else np.broadcast_to(buffers[f], (samples, *buffers[f].shape))
                for f in sample_features
            ]
            buffers[SAMPLES] = np.ascontiguousarray(np.concatenate(per_sample, axis=1))
        frames.append({k: buffers[k] for k in inputs if k in buffers})
    return frames
