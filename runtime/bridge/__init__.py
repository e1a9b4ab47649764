"""How ONNX Runtime reaches the fast kernels: the chooser of the bridge.

Three ways register fast forms of the ops as the custom ops `rtdenoise::<Name>`, which then
take precedence over the model-local function body of the same name (docs/architecture.md,
"The three forms" and "How ONNX Runtime reaches the fast kernels"):

- `native-cpp` (`native_cpp.py`, the C++ library `native_ops/`): the ops' own C++ kernels, no
  Python in the run; chosen by default for a model when it was built and holds every
  rtdenoise op of that model (`RTDENOISE_NATIVE_OPS=0` or an explicit bridge turns it off);

and two bridges to the numba kernels of `runtime/kernels/`, for every `KERNELS` entry, which
need numba (the `numba` extra; nothing here imports it before one of them is chosen):

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
import importlib.util
import os
import warnings
from collections.abc import Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext

import onnxruntime as ort

from .calls import CALLS, KernelError, raise_kernel_errors, take_kernel_error

BRIDGES = ("native-cpp", "native", "extensions")
NUMBA_BRIDGES = ("native", "extensions")

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


def numba_installed() -> bool:
    """True when numba can be imported (the `numba` extra), found without importing it."""
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):  # an import hook refuses it; a half-imported module
        return False


def choose_bridge(ops: Iterable[str] | None) -> str:
    """The bridge for a model whose rtdenoise ops are `ops` (None: not known): "native-cpp"
    when the C++ library is built and holds all of them and RTDENOISE_NATIVE_OPS does not
    turn it off; else the best numba bridge (`default_bridge`), or, where
    numba is not installed, ModuleNotFoundError saying why the library cannot run them."""
    from . import native_cpp

    if (
        ops is not None
        and not native_cpp.disabled_by_env()
        and native_cpp.available()
        and not native_cpp.missing_ops(ops)
    ):
        return "native-cpp"
    if not numba_installed():
        raise _no_numba("the C++ library " + _native_cpp_refusal(ops))
    return default_bridge()


def _native_cpp_refusal(ops: Iterable[str] | None) -> str:
    """Why the C++ library cannot run every op of `ops` here (which the caller found), as a
    phrase: "is turned off by RTDENOISE_NATIVE_OPS=0"."""
    from . import native_cpp

    if native_cpp.disabled_by_env():
        return f"is turned off by {native_cpp.ENV_SWITCH}={os.environ[native_cpp.ENV_SWITCH]}"
    reason = native_cpp.unavailable_reason()
    if reason is not None:
        return f"is unavailable ({reason})"
    if ops is None:
        return "is not chosen for a model whose ops are not known"
    return f"lacks {', '.join(native_cpp.missing_ops(ops))}"


def _no_numba(context: str) -> ModuleNotFoundError:
    return ModuleNotFoundError(f"numba is not installed and {context}", name="numba")


def register_fast_kernels(
    so: ort.SessionOptions, bridge: str | None = None, ops: Iterable[str] | None = None
) -> str:
    """Make sessions created with `so` run the rtdenoise ops with fast kernels, through
    `bridge`: "native-cpp" (the C++ library's own kernels; ValueError where it is not built or
    lacks one of `ops`), "native" (the numba kernels, no copies; the default where it was
    built) or "extensions" (onnxruntime-extensions' Python ops, which copy every input and
    output); None: `choose_bridge(ops)`, `ops` the model's rtdenoise op types. Returns the
    bridge used. ValueError for another name; ModuleNotFoundError when numba (or, for
    "extensions", onnxruntime-extensions) is not installed and the bridge needs it."""
    if bridge not in (None, *BRIDGES):
        raise ValueError(f"unknown fast-kernel bridge {bridge!r}; expected one of {BRIDGES}")
    if bridge in NUMBA_BRIDGES and not numba_installed():
        raise _no_numba(f"the {bridge!r} bridge runs the numba kernels")
    bridge = bridge or choose_bridge(ops)
    if bridge == "native-cpp":
        from . import native_cpp

        reason = native_cpp.unavailable_reason()
        missing = native_cpp.missing_ops(ops or ()) if reason is None else []
        if reason or missing:
            raise ValueError(reason or f"the C++ library rtdenoise_ops lacks {', '.join(missing)}")
        native_cpp.register(so)
        return bridge
    importlib.import_module(f".{bridge}", __name__).register(so)
    return bridge


def kernel_threads(bridge: str, threads: int | None) -> AbstractContextManager[None]:
    """Run this thread's fast kernels on `bridge` with `threads` threads (None: the kernels'
    own default, every core): the C++ library's count for "native-cpp", numba's otherwise."""
    if bridge == "native-cpp":
        from . import native_cpp

        return native_cpp.threads(threads)
    return numba_threads(threads)


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
    "NUMBA_BRIDGES",
    "choose_bridge",
    "default_bridge",
    "kernel_threads",
    "numba_installed",
    "numba_threads",
    "raise_kernel_errors",
    "register_fast_kernels",
    "take_kernel_error",
]
