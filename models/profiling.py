"""Named pipeline stages, timed on request: `with stage("unet"): ...` inside a model's forward,
and `with timed_stages() as ms: model(...)` around it collects the wall time of each stage (ms).
Free when nothing listens, and a no-op while a model is traced for export."""

from __future__ import annotations

import contextlib
import time
from collections import defaultdict
from collections.abc import Iterator

import torch

from .ops.export_mode import use_custom_op

_listeners: list[dict[str, float]] = []


@contextlib.contextmanager
def stage(name: str) -> Iterator[None]:
    """Add the wall time of this block to every `timed_stages` listener under `name`."""
    if not _listeners or use_custom_op() or torch.compiler.is_compiling():
        yield
        return
    t0 = time.perf_counter()
    try:
        yield
    finally:
        ms = (time.perf_counter() - t0) * 1e3
        for times in _listeners:
            times[name] += ms


@contextlib.contextmanager
def timed_stages() -> Iterator[dict[str, float]]:
    """{stage name: ms} of the `stage` blocks run inside this block."""
    times: dict[str, float] = defaultdict(float)
    _listeners.append(times)
    try:
        yield times
    finally:
        _listeners.remove(times)
