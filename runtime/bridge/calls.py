"""What the fast kernels did inside ONNX Runtime: calls per op, and each thread's first failure.

Both custom-op bridges (`native`, the default, and `extensions`)
count their calls here and record a kernel's exception instead of letting it leave the op: an
exception unwinding through ONNX Runtime's C boundary aborts the process. `raise_kernel_errors`
(which `Denoiser` wraps around every run) raises it once the run has returned. No torch here.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

# Calls per op through ORT (tests use it to prove the fast kernel ran).
CALLS: Counter[str] = Counter()


class KernelError(RuntimeError):
    """A fast kernel raised inside ONNX Runtime; the original exception is its __cause__."""


# The first exception a kernel raised in this thread since the last `raise_kernel_errors`.
_pending = threading.local()


def record_failure(exc: BaseException, op: str) -> None:
    """Remember the first failure of this thread's run (never raises)."""
    try:
        if getattr(_pending, "error", None) is None:
            _pending.error, _pending.op = exc, op
    except BaseException:  # nothing may leave an op
        pass


def nan_outputs(shapes: Sequence[tuple[int, ...]]) -> tuple[np.ndarray, ...]:
    """NaN arrays of `shapes` (zero-size ones if even that fails): what a failed op returns."""
    try:
        return tuple(np.full(s, np.nan, np.float32) for s in shapes)
    except BaseException:
        return tuple(np.zeros((0,), np.float32) for _ in shapes)


def take_kernel_error() -> tuple[BaseException, str] | None:
    """(exception, op name) of the first kernel failure in this thread since the last call,
    cleared; None if there was none."""
    error = getattr(_pending, "error", None)
    _pending.error = None
    return None if error is None else (error, _pending.op)


@contextmanager
def raise_kernel_errors() -> Iterator[None]:
    """Wrap `session.run`: a kernel's exception is raised here, after the run returned.

    KeyboardInterrupt and SystemExit are re-raised as they are; any other exception as a
    `KernelError` naming the op, chained to the original. A host driving a session with
    `register_fast_kernels` itself wraps its runs in this (the outputs of a run whose kernel
    failed are NaN, never a crash).
    """
    take_kernel_error()  # a stale failure of an unchecked run is not this run's
    try:
        yield
    except BaseException:  # e.g. ONNX Runtime failing on a failed op's empty output
        failure = take_kernel_error()
        if failure is None:
            raise
        raise _as_raised(*failure)  # noqa: B904  (the kernel's error is the cause)
    failure = take_kernel_error()
    if failure is not None:
        raise _as_raised(*failure)


def _as_raised(exc: BaseException, op: str) -> BaseException:
    """What the caller sees of a kernel's exception: interrupts as they are, else KernelError."""
    if not isinstance(exc, Exception):  # KeyboardInterrupt, SystemExit, ...
        return exc
    first = (str(exc).strip().splitlines() or [""])[0]
    error = KernelError(f"fast kernel {op} failed: {type(exc).__name__}: {first}")
    error.__cause__ = exc
    return error
