"""checkpoint -> validated .onnx: the whole `denoise-export` job as one function."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx

from rtdenoise.models.base import DenoiserModel
from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.runtime.sequences.atomic import write_bytes_atomic

from .deploy import to_deploy
from .onnx_export import export_model
from .validate import ValidationReport, synthetic_frames, validate


class ExportValidationError(RuntimeError):
    """ONNX Runtime disagrees with PyTorch beyond the tolerance: nothing was written."""


@dataclass
class ExportReport:
    path: Path | None
    family: str
    nodes: int
    custom_nodes: dict[str, int]
    parameters: int
    size_bytes: int
    validation: ValidationReport
    frame_size: tuple[int, int]
    source: str


def validation_frames(
    model: DenoiserModel, n: int, size: int = 64
) -> tuple[list[dict[str, np.ndarray]], str]:
    """Frames to validate on: a bundled rendered sequence when one is shipped, else synthetic."""
    from rtdenoise.runtime.contract import SAMPLES
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame
    from rtdenoise.runtime.sequences.samples import sample_features_of
    from rtdenoise.shipped import sample_sequences

    pad = model.pad_multiple
    h = w = max(pad, size - size % pad)
    features = sample_features_of(model.config()) if SAMPLES in model.inputs else None
    for seq in sample_sequences():
        paths = find_frames(seq)
        frames = [read_frame(p, sample_features=features).buffers for p in paths[:n]]
        if len(frames) < n or not all(k in frames[0] for k in model.inputs):
            continue
        fh, fw = frames[0]["color"].shape[-2:]
        if fh < h or fw < w:
            continue
        cropped = [
            {k: np.ascontiguousarray(f[k][..., :h, :w]) for k in model.inputs} for f in frames
        ]
        return cropped, f"bundled sequence {seq.name}"
    synthetic = synthetic_frames(model.inputs, n, h, w, sample_features=features or ())
    return synthetic, "synthetic"


def count_nodes(proto: onnx.ModelProto) -> tuple[int, dict[str, int]]:
    custom: dict[str, int] = {}
    for node in proto.graph.node:
        if node.domain == "rtdenoise":
            custom[node.op_type] = custom.get(node.op_type, 0) + 1
    return len(proto.graph.node), custom


def check_finite_weights(model: DenoiserModel, source: str | os.PathLike) -> None:
    """ValueError naming the first parameter or buffer of `model` that holds NaN/Inf (a
    diverged training run): exported, it would give NaN frames on every input, and the
    validation against PyTorch could only compare NaN with NaN."""
    import torch

    bad = []
    for name, tensor in model.state_dict().items():
        if torch.is_floating_point(tensor):
            count = int((~torch.isfinite(tensor)).sum())
            if count:
                bad.append((name, tuple(tensor.shape), count, tensor.numel()))
    if bad:
        name, shape, count, total = bad[0]
        more = f" (and {len(bad) - 1} more tensors)" if len(bad) > 1 else ""
        raise ValueError(
            f"{source}: weight {name!r} {shape} has {count} NaN/Inf of {total} values{more}; "
            "the checkpoint is broken (a diverged training run?): not exported"
        )


def export_checkpoint(
    checkpoint: str | os.PathLike,
    output: str | os.PathLike | None,
    *,
    frames: int = 8,
    size: int = 64,
    tolerance: float = 1e-4,
) -> ExportReport:
    """Load, export, validate over `frames` frames, write `output` atomically (None: don't).

    Raises ExportValidationError (and writes nothing) when ORT and PyTorch disagree.
    """
    model, _meta = load_checkpoint(checkpoint)
    check_finite_weights(model, checkpoint)
    model.eval()
    proto = export_model(model)
    data = proto.SerializeToString()
    seq, source = validation_frames(model, frames, size)
    report = validate(model, data, seq, tolerance=tolerance)
    nodes, custom = count_nodes(proto)
    params = sum(p.numel() for p in to_deploy(model).parameters())  # folded, as deployed
    result = ExportReport(
        path=None,
        family=model.family,
        nodes=nodes,
        custom_nodes=custom,
        parameters=params,
        size_bytes=len(data),
        validation=report,
        frame_size=tuple(seq[0][model.inputs[0]].shape[-2:]),
        source=source,
    )
    if not report.passed:
        raise ExportValidationError(
            f"ONNX Runtime disagrees with PyTorch: max error {report.max_error:.3g} > "
            f"tolerance {tolerance:.3g}; {output} not written"
        )
    if output is not None:
        result.path = write_bytes_atomic(Path(output), data)
    return result
