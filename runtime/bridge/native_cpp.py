"""The `native-cpp` path: the C++ custom-op library `rtdenoise_ops`, no Python in the run.

`native_ops/` (C++17, built by `pip install` where a compiler exists, setup.py) is an ordinary
ONNX Runtime custom-op library: `RegisterCustomOps` adds its ops to the `rtdenoise` domain,
and each runs its own forward kernel (the numba kernel's arithmetic, each pixel's terms in its
order, blocked and vectorised differently; CrossRegression's exp a polynomial within about
1 ulp of numba's, so within 1e-5, not bit for bit) on ORT's buffers, with its errors returned
as ORT statuses naming the op and the cause. A C or C++
host loads the same file. From Python, this module finds it, says which ops it holds, and
sets its thread count around a run (`threads`), as `numba_threads` does for numba.

The library also exports the input guard as C functions (native_ops/rtdenoise_guard.h, the
rules of runtime/guard.py for C and C++ hosts; examples/host_c/host.c calls them): the
runtime guards in Python, and `guard_buffer` / `zero_guide` here call the C form only so that
tests/test_native_guard.py can compare the two bit for bit.

It holds only some ops (`covered_ops`); the chooser (`bridge.register_fast_kernels`) picks it
for a model when it holds every rtdenoise op of that model (each of its ops measured faster
than its numba kernel or within the noise of one run: benchmarks/README.md). No numba, no
torch here.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path
from typing import NamedTuple

import numpy as np
import onnxruntime as ort

FILE = {"win32": "rtdenoise_ops.dll", "darwin": "librtdenoise_ops.dylib"}.get(
    sys.platform, "librtdenoise_ops.so"
)
# "0" (or "off", "numba"): never choose this library by default (the numba kernels run).
ENV_SWITCH = "RTDENOISE_NATIVE_OPS"
ABI = 1  # rtdenoise_ops_abi() of the library this module speaks to


class NativeOpsError(RuntimeError):
    """The library cannot be used (not built, or not the one this module expects)."""


def library_path() -> str | None:
    """The built library's file, or None if the package was installed without it."""
    path = Path(__file__).with_name(FILE)
    return os.path.realpath(path) if path.is_file() else None


@cache
def _library() -> ctypes.CDLL:
    path = library_path()
    if path is None:
        raise NativeOpsError(f"{FILE} was not built (no C++17 compiler at install?)")
    lib = ctypes.CDLL(path)  # ORT's dlopen of the same file shares its globals
    lib.rtdenoise_ops_abi.restype = ctypes.c_int
    if lib.rtdenoise_ops_abi() != ABI:
        raise NativeOpsError(f"{path} speaks ABI {lib.rtdenoise_ops_abi()}, expected {ABI}")
    lib.rtdenoise_ops_names.restype = ctypes.c_char_p
    lib.rtdenoise_ops_set_threads.argtypes = [ctypes.c_int]
    lib.rtdenoise_ops_set_threads.restype = ctypes.c_int
    return lib


def unavailable_reason() -> str | None:
    """Why the library cannot be used (None: it loads)."""
    try:
        _library()
        return None
    except (NativeOpsError, OSError) as exc:
        return str(exc)


def available() -> bool:
    return unavailable_reason() is None


def covered_ops() -> frozenset[str]:
    """The rtdenoise ops the library holds (empty when it is not built)."""
    if not available():
        return frozenset()
    names = (_library().rtdenoise_ops_names() or b"").decode()
    return frozenset(n for n in names.split(",") if n)


def missing_ops(ops: Iterable[str]) -> list[str]:
    """The ops of `ops` that the library does not hold, sorted."""
    return sorted(set(ops) - covered_ops())


def disabled_by_env() -> bool:
    """True when RTDENOISE_NATIVE_OPS asks for the numba kernels."""
    return os.environ.get(ENV_SWITCH, "").strip().lower() in ("0", "off", "false", "no", "numba")


def register(options: ort.SessionOptions) -> None:
    """Make sessions created with `options` run the ops the library holds with its kernels."""
    _library()
    options.register_custom_ops_library(library_path())


@contextmanager
def threads(count: int | None) -> Iterator[None]:
    """Run this thread's ops with `count` threads (None: the library's default, every core
    or RTDENOISE_OPS_THREADS), restored after; the setting belongs to the calling thread,
    which is the one ORT runs the custom ops on."""
    lib = _library()
    before = lib.rtdenoise_ops_set_threads(max(0, int(count or 0)))
    try:
        yield
    finally:
        lib.rtdenoise_ops_set_threads(before)


class GuardResult(NamedTuple):
    """What the C guard did to one buffer: the fields of `runtime.guard.Guarded` (the bridge
    does not import the runtime's host wing, tests/test_layers.py)."""

    array: np.ndarray  # the guarded copy
    nonfinite: np.ndarray | None  # (H, W) mask of pixels that had NaN/Inf, None: none had
    clamped: int
    outliers: int
    zero: bool


class GuardCounts(ctypes.Structure):
    """rtdenoise_guard_counts (native_ops/rtdenoise_guard.h)."""

    _fields_ = [
        ("nonfinite", ctypes.c_int64),
        ("clamped", ctypes.c_int64),
        ("outliers", ctypes.c_int64),
        ("zero", ctypes.c_int32),
        ("reserved", ctypes.c_int32),
    ]


@cache
def guard_library() -> ctypes.CDLL:
    """The library with the guard's C functions declared (rtdenoise_guard.h)."""
    lib = _library()
    p, i64 = ctypes.c_void_p, ctypes.c_int64
    lib.rtdenoise_guard_buffer.argtypes = [
        ctypes.c_char_p, p, p, i64, i64, i64, ctypes.POINTER(GuardCounts), p
    ]  # fmt: skip
    lib.rtdenoise_guard_buffer.restype = ctypes.c_int
    lib.rtdenoise_guard_zero_guide.argtypes = [ctypes.c_char_p, p, i64]
    lib.rtdenoise_guard_zero_guide.restype = ctypes.c_int
    lib.rtdenoise_guard_error.argtypes = [ctypes.c_int]
    lib.rtdenoise_guard_error.restype = ctypes.c_char_p
    return lib


def _guard_error(call: str, code: int) -> ValueError:
    return ValueError(f"{call}: {guard_library().rtdenoise_guard_error(code).decode()} ({code})")


def guard_buffer(name: str, array: np.ndarray, *, in_place: bool = True) -> GuardResult:
    """The C guard (`rtdenoise_guard_buffer`) on a float32 copy of `array` (..., H, W): what
    `runtime.guard.guard_buffer` returns, computed by the library (its array always a new
    one). in_place=False: the C function reads the copy and writes another array (its
    input/output form). ValueError for what the C function refuses (an empty array)."""
    a = np.array(array, dtype=np.float32, order="C", copy=True)
    if a.ndim < 2:
        raise ValueError(f"guard_buffer: needs an (..., H, W) array, got shape {a.shape}")
    h, w = a.shape[-2:]
    planes = int(np.prod(a.shape[:-2], dtype=np.int64))
    out = a if in_place else np.full_like(a, np.nan)
    mask = np.zeros((h, w), np.uint8)
    counts = GuardCounts()
    code = guard_library().rtdenoise_guard_buffer(
        name.encode(), a.ctypes.data, out.ctypes.data, planes, h, w, ctypes.byref(counts),
        mask.ctypes.data,
    )  # fmt: skip
    if code:
        raise _guard_error(f"rtdenoise_guard_buffer({name!r}, shape {a.shape})", code)
    nonfinite = mask.astype(bool) if counts.nonfinite else None
    return GuardResult(out, nonfinite, int(counts.clamped), int(counts.outliers), bool(counts.zero))


def zero_guide(name: str, array: np.ndarray) -> bool:
    """`rtdenoise_guard_zero_guide`: True when `name` is a guide buffer (albedo, normal, depth)
    and every value of `array` is 0."""
    a = np.ascontiguousarray(array, np.float32)
    code = guard_library().rtdenoise_guard_zero_guide(name.encode(), a.ctypes.data, a.size)
    if code < 0:
        raise _guard_error(f"rtdenoise_guard_zero_guide({name!r}, shape {a.shape})", code)
    return bool(code)
