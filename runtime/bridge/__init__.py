"""How ONNX Runtime reaches the fast kernels (`runtime/kernels/`): the chooser of the bridge.

Two bridges register every `KERNELS` entry as the custom op `rtdenoise::<Name>`, which then
takes precedence over the model-local function body of the same name (docs/architecture.md,
"The three forms" and "two bridges"):

- `native` (`native.py` + the compiled `_ort_bridge.c`): ONNX Runtime hands the kernels its
  own buffers, nothing is copied; the default wherever it was built;
- `extensions` (`extensions.py`): onnxruntime-extensions' Python ops, which copy every input
  and output; the fallback. onnxruntime-extensions is imported only when this bridge is
  chosen, so the native bridge works without it installed.

Both count calls and record a kernel's failure in `calls.py` (nothing may unwind through ONNX
Runtime's C boundary); `raise_kernel_errors()` raises it after the run. No torch here.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

import onnxruntime as ort

from .calls import CALLS, KernelError, raise_kernel_errors, take_kernel_error

BRIDGES = ("native", "extensions")

_fallback_warned = False


def default_bridge() -> str:
    """ "native" when the compiled bridge loads, else "extensions", saying once per process
    why (the copies cost ~20 % of a 720p frame)."""
    global _fallback_warned
    from . import native

    reason = native.unavailable_reason()
    if reason is None:
        return "native"
    if not _fallback_warned:
        _fallback_warned = True
        warnings.warn(
            f"native custom-op bridge unavailable ({reason}): the fast kernels run through "
            "onnxruntime-extensions, which copies every input and output (about 20 % slower "
            "at 720p); reinstall with a C compiler to build it",
            RuntimeWarning,
            stacklevel=3,
        )
    return "extensions"


def register_fast_kernels(so: ort.SessionOptions, bridge: str | None = None) -> str:
    """Make sessions created with `so` run the rtdenoise ops with the numba kernels, through
    `bridge`: "native" (no copies; the default where it was built) or "extensions"
    (onnxruntime-extensions' Python ops, which copy every input and output). Returns the
    bridge used. ValueError for another name; ModuleNotFoundError when numba (or, for
    "extensions", onnxruntime-extensions) is not installed."""
    if bridge not in (None, *BRIDGES):
        raise ValueError(f"unknown fast-kernel bridge {bridge!r}; expected one of {BRIDGES}")
    bridge = bridge or default_bridge()
    importlib.import_module(f".{bridge}", __name__).register(so)
    return bridge


def numba_threads(threads: int | None) -> AbstractContextManager[None]:
    """Run this thread's kernels with `threads` numba threads (None: leave numba's setting).

    numba's thread count belongs to the calling thread, and ONNX Runtime runs a custom op on
    the thread that called `session.run`: so the count is set around each run, on the thread
    that runs it, capped at numba's pool size (NUMBA_NUM_THREADS), and restored after.
    """
    return nullcontext() if threads is None else _numba_threads(threads)


@contextmanager
def _numba_threads(threads: int) -> Iterator[None]:
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


__all__ = [
    "BRIDGES",
    "CALLS",
    "KernelError",
    "default_bridge",
    "numba_threads",
    "raise_kernel_errors",
    "register_fast_kernels",
    "take_kernel_error",
]
