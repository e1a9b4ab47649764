"""Speed of a denoiser at a real frame size: PyTorch eager vs ORT-fast vs ORT-portable.

Measured in one run, side by side, on the same frames (medians over `repeats` frames after
a warm-up frame, state fed back as in production):
- whole model: PyTorch eager (training form), PyTorch eager (deployed form), ORT with the
  fast kernels, ORT portable (function bodies inlined);
- per stage: every filter-stage call the model makes (found by recording the calls of
  `rtdenoise.models.ops` during one forward), timed inside the real PyTorch forward and as
  single-op ONNX models on ORT (fast and portable) and as the bare numba kernel;
  "network and glue" = whole model minus the stages.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from rtdenoise.models import ops as torch_ops
from rtdenoise.models.base import DenoiserModel
from rtdenoise.runtime.denoiser import Denoiser

from .deploy import to_deploy
from .onnx_export import export_model
from .ops.bench import bench_op
from .validate import synthetic_frames

PATHS = ("torch", "torch_deployed", "ort_fast", "ort_portable")


@dataclass
class StageCall:
    op: str
    shape: tuple[int, ...]
    attrs: dict[str, int]
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
    """Wrap every public op function of rtdenoise.models.ops to record shapes and time."""
    originals = {}
    for op_name, (public, _custom, _ref) in torch_ops.OPS.items():
        attr = public.__name__
        originals[attr] = getattr(torch_ops, attr)

        def timed(*args, _op=op_name, _fn=public, **kwargs):
            t0 = time.perf_counter()
            out = _fn(*args, **kwargs)
            dt = (time.perf_counter() - t0) * 1000.0
            attrs = _stage_attrs(_op, args, kwargs)
            key = (_op, tuple(args[0].shape), tuple(sorted(attrs.items())))
            match = calls.setdefault(key, StageCall(_op, tuple(args[0].shape), attrs))
            match.torch_ms.append(dt)
            return out

        setattr(torch_ops, attr, timed)
    try:
        yield
    finally:
        for attr, fn in originals.items():
            setattr(torch_ops, attr, fn)


def _stage_attrs(op: str, args: tuple, kwargs: dict) -> dict[str, int]:
    if op == "KernelApply":
        k = int(round(args[1].shape[1] ** 0.5))
        dilation = int(kwargs.get("dilation", args[2] if len(args) > 2 else 1))
        return {"kernel_size": k, "dilation": dilation}
    return {}


def _time_torch(model: DenoiserModel, frames: list[dict[str, np.ndarray]]) -> list[float]:
    h, w = frames[0]["color"].shape[-2:]
    state = model.initial_state(1, h, w)
    times = []
    with torch.no_grad():
        for i, frame in enumerate(frames):
            buffers = {k: torch.from_numpy(frame[k])[None] for k in model.inputs}
            t0 = time.perf_counter()
            _, state = model(buffers, state, torch.tensor(1.0 if i == 0 else 0.0))
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
    frames = synthetic_frames(model.inputs, repeats + 1, *size)
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
            call.op, call.shape, repeats=repeats, attrs=call.attrs or None, threads=threads or 0
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
