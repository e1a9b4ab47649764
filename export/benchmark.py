"""Speed of a denoiser at a real frame size: PyTorch eager vs ORT-fast vs ORT-portable.

Measured in one run, side by side, on the same frames (medians over `repeats` frames after
a warm-up frame, state fed back as in production):
- whole model: PyTorch eager (training form), PyTorch eager (deployed form), ORT with the
  fast kernels, ORT portable (function bodies inlined);
- per stage: every filter-stage call the model makes (recorded with
  `rtdenoise.models.ops.observe_calls`: op, shapes, attributes, the very input tensors), timed
  inside the real PyTorch forward and, on those same inputs, as single-op ONNX models on ORT
  (fast and portable) and as the bare numba kernel;
  "network and glue" = whole model minus the stages.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from rtdenoise.models.base import DenoiserModel
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.models.ops import TorchOp, observe_calls
from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.sequences.samples import sample_features_of

from .deploy import to_deploy
from .onnx_export import export_model
from .op_bench import bench_op
from .validate import synthetic_frames

PATHS = ("torch", "torch_deployed", "ort_fast", "ort_portable")


@dataclass
class StageCall:
    """The calls of one op with one input shape and attribute set during a frame."""

    op: str
    shape: tuple[int, ...]
    attrs: dict[str, int]
    inputs: list[np.ndarray]  # the tensors of the first such call (benchmarked as is)
    torch_ms: list[float] = field(default_factory=list)


@dataclass
class BenchResult:
    size: tuple[int, int]
    model_ms: dict[str, float]
    stages: list[dict]
    threads: int


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


@contextmanager
def _record_stages(calls: dict[tuple, StageCall]):
    """Record every filter-stage call (op, shapes, attributes, time) inside this block."""

    def record(op: TorchOp, inputs: tuple, attrs: dict[str, int], ms: float) -> None:
        shapes = tuple(tuple(x.shape) for x in inputs)
        key = (op.name, shapes, tuple(sorted(attrs.items())))
        if key not in calls:
            arrays = [x.detach().numpy().copy() for x in inputs]
            calls[key] = StageCall(op.name, shapes[0], dict(attrs), arrays)
        calls[key].torch_ms.append(ms)

    with observe_calls(record):
        yield


def _time_torch(model: DenoiserModel, frames: list[dict[str, np.ndarray]]) -> list[float]:
    loop = FrameLoop(model)
    times = []
    with torch.no_grad():
        for frame in frames:
            t0 = time.perf_counter()
            loop(frame)
            times.append((time.perf_counter() - t0) * 1000.0)
    return times[1:]  # frame 0 is the warm-up


def _time_ort(onnx_bytes: bytes, frames, *, fast: bool, threads: int | None) -> list[float]:
    denoiser = Denoiser(onnx_bytes, fast_kernels=fast, threads=threads)
    times = []
    for frame in frames:
        t0 = time.perf_counter()
        denoiser.process(frame)
        times.append((time.perf_counter() - t0) * 1000.0)
    return times[1:]


def benchmark_model(
    model: DenoiserModel,
    size: tuple[int, int] = (720, 1280),
    repeats: int = 5,
    threads: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> BenchResult:
    """Time `model` at `size` (H, W) in every path; see the module docstring."""
    say = progress or (lambda _msg: None)
    if threads:
        torch.set_num_threads(threads)
    model = model.eval()
    deployed = to_deploy(model)
    features = sample_features_of(model.config()) if SAMPLES in model.inputs else ()
    frames = synthetic_frames(model.inputs, repeats + 1, *size, sample_features=features)
    say("exporting")
    onnx_bytes = export_model(model).SerializeToString()

    model_ms: dict[str, float] = {}
    calls: dict[tuple, StageCall] = {}
    say("PyTorch eager (training form)")
    with _record_stages(calls):
        model_ms["torch"] = _median(_time_torch(model, frames))
    say("PyTorch eager (deployed form)")
    model_ms["torch_deployed"] = _median(_time_torch(deployed, frames))
    say("ORT fast")
    model_ms["ort_fast"] = _median(_time_ort(onnx_bytes, frames, fast=True, threads=threads))
    say("ORT portable")
    model_ms["ort_portable"] = _median(_time_ort(onnx_bytes, frames, fast=False, threads=threads))

    stages = []
    for call in calls.values():
        say(f"stage {call.op} {call.shape}")
        forms = bench_op(
            call.op,
            call.shape,
            repeats=repeats,
            attrs=call.attrs,
            threads=threads or 0,
            inputs=call.inputs,
        )["ms"]
        stages.append(
            {
                "op": call.op,
                "shape": list(call.shape),
                "attrs": call.attrs,
                "calls_per_frame": len(call.torch_ms) // len(frames),
                "ms": {
                    "torch": _median(
                        call.torch_ms[1:] if len(call.torch_ms) > 1 else call.torch_ms
                    ),
                    "ort_fast": forms["ort_fast"],
                    "ort_portable": forms["ort_portable"],
                    "numba": forms["numba"],
                },
            }
        )
    return BenchResult(size=size, model_ms=model_ms, stages=stages, threads=threads or 0)
