"""The export-mode switch: differentiable torch form of a filter stage, or its export node.

Model code calls one public function per op (e.g. `kernel_apply`). Normally it runs the
plain differentiable torch implementation (training, numeric reference). While the model
is being exported it calls the op's `torch.library.custom_op` instead, so that the op
becomes ONE node (`torch.ops.rtdenoise.<op>`) that the ONNX exporter translates into the
custom node `rtdenoise.<Op>` (docs/architecture.md, "The three forms").

The switch is on when either `torch.compiler.is_exporting()` is true (set by
`torch.export`, which `torch.onnx.export(dynamo=True)` uses) or the `exporting()` context
manager is active (for tracers that do not set that flag).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator

import torch

_state = threading.local()


@contextlib.contextmanager
def exporting(enabled: bool = True) -> Iterator[None]:
    """Force (or, with `enabled=False`, forbid) the custom-op form inside this block."""
    previous = getattr(_state, "mode", None)
    _state.mode = enabled
    try:
        yield
    finally:
        _state.mode = previous


def use_custom_op() -> bool:
    """True when the public op functions must emit their custom op (export) node."""
    mode = getattr(_state, "mode", None)
    if mode is not None:
        return mode
    return bool(torch.compiler.is_exporting())
