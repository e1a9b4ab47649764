"""Progress a long command reports on stderr: plain lines where stderr is no terminal (a log,
a pipe, CI), where rich's live bar shows nothing; and the fast kernels' compilation.

numba compiles a kernel on its first call and caches it on disk, so the first run of a model
on a machine spends up to a minute there before its first frame (docs: README, "GPU: status
and caveats"). `kernel_compilation` reports each compilation numba really does (its
"numba:compile" event fires on a cache miss only): one line when the outermost compile
starts, one with its time when it ends.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any


def plain_line(message: str) -> None:
    """One progress line on stderr, flushed (a log shows it at once)."""
    print(message, file=sys.stderr, flush=True)


def _listener(say: Callable[[str], None]) -> Any:
    from numba.core import event

    class CompileLines(event.Listener):
        """The outermost numba compilation only (a kernel compiles the functions it
        inlines inside its own event)."""

        def __init__(self) -> None:
            self.depth = 0
            self.started = 0.0
            self.name = ""

        def on_start(self, ev: Any) -> None:
            self.depth += 1
            if self.depth == 1:
                dispatcher = (ev.data or {}).get("dispatcher")
                name = getattr(getattr(dispatcher, "py_func", None), "__name__", "kernel")
                self.name = name.strip("_").removesuffix("_nb")  # _softmax_nb -> softmax
                self.started = time.perf_counter()
                say(f"compiling fast kernel {self.name} (numba; first run only, then cached)")

        def on_end(self, ev: Any) -> None:
            self.depth -= 1
            if self.depth == 0:
                seconds = time.perf_counter() - self.started
                say(f"compiled fast kernel {self.name} in {seconds:.1f} s")

    return CompileLines()


@contextmanager
def kernel_compilation(say: Callable[[str], None]) -> Iterator[None]:
    """Within the block, `say` hears of every kernel numba compiles (nothing without numba:
    the portable path compiles nothing)."""
    try:
        from numba.core import event
    except ImportError:
        yield
        return
    with event.install_listener("numba:compile", _listener(say)):
        yield


__all__ = ["kernel_compilation", "plain_line"]
