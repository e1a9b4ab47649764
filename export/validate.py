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
from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.layout import has_layout_flag
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: F401  (re-exported)


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
    """Compare PyTorch with ORT-fast and ORT-portable over `frames`; a model with layout
    forms (docs/contract.md) on the fast path in each form."""
    reference = torch_outputs(model.eval(), frames)
    report = ValidationReport(tolerance=tolerance)
    paths: list[tuple[str, bool, str | None]] = [("ort_fast", True, None)]
    if has_layout_flag(onnx_bytes):
        paths = [("ort_fast", True, "plain"), ("ort_fast_nchwc16", True, "nchwc16")]
    for path, fast, layout in (*paths, ("ort_portable", False, None)):
        denoiser = Denoiser(onnx_bytes, fast_kernels=fast, layout=layout)
        report.errors[path] = [
            frame_error(denoiser.process(frame), ref)
            for frame, ref in zip(frames, reference, strict=True)
        ]
    return report
