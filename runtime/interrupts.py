"""Hold Python signal handlers (Ctrl-C) while ONNX Runtime runs, then run them.

Python runs a signal handler in the main thread at its next bytecode, which during
`session.run` is inside a Python custom op (the fast kernels): the KeyboardInterrupt that
`default_int_handler` raises there would leave the op and abort the process
(`runtime/bridge/extensions.py`). Inside `deferred_signals()` a SIGINT or SIGTERM whose handler is a
Python function is only noted; the handler runs when the block ends, in ordinary Python code,
so Ctrl-C still raises KeyboardInterrupt, one frame later at most. Elsewhere than in the main
thread (where Python never runs handlers) it does nothing.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

DEFERRED_SIGNALS = tuple(
    s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None)) if s
)


@contextmanager
def deferred_signals() -> Iterator[None]:
    """Note SIGINT / SIGTERM meanwhile; run their Python handlers when the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[tuple[int, FrameType | None]] = []

    def note(signum: int, frame: FrameType | None) -> None:
        received.append((signum, frame))

    previous = {}
    try:
        for sig in DEFERRED_SIGNALS:
            handler = signal.getsignal(sig)
            if callable(handler):
                previous[sig] = handler
                signal.signal(sig, note)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for signum, frame in received:
            previous[signum](signum, frame)  # default_int_handler raises KeyboardInterrupt


__all__ = ["DEFERRED_SIGNALS", "deferred_signals"]
