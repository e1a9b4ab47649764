"""The native custom-op bridge: ONNX Runtime runs the fast kernels on its own buffers.

`_ort_bridge.c` (compiled when the package is installed) is a custom-op library in ONNX
Runtime's C ABI. Each `rtdenoise.runtime.kernels.KERNELS` entry is declared to it once; a
session's options then register it (`register(options)`), and every call of an op reaches
`_compute` below with ORT's input and output buffers, which the numba driver reads and fills
as numpy views: nothing is copied, unlike onnxruntime-extensions' Python ops (which copy every
input and output: ~200-300 ms per 720p frame of the light demos, benchmarks/README.md).

The output shapes come from the op's spec (`_shapes`), checked as `FastKernel` checks a call.
Nothing leaves a callback: a failure is recorded (`calls`) and its outputs are NaN (or
empty when their shapes are unknown); `calls.raise_kernel_errors` raises it after the
run, as for the other bridge. No torch here.
"""

from __future__ import annotations

import ctypes
import importlib.util
import math
import os
from ctypes import POINTER, c_char_p, c_int, c_int64, c_void_p

import numpy as np
import onnxruntime as ort

from ..kernels import KERNELS, FastKernel
from .calls import CALLS, record_failure

MAX_RANK = 8  # as in _ort_bridge.c
LIBRARY = "rtdenoise.runtime.bridge._ort_bridge"

_Dims = POINTER(c_int64)
_SHAPE = ctypes.CFUNCTYPE(c_int, c_int, c_int, _Dims, _Dims, _Dims, _Dims, _Dims)
_COMPUTE = ctypes.CFUNCTYPE(
    c_int, c_int, c_int, POINTER(c_void_p), _Dims, _Dims, c_int, POINTER(c_void_p), _Dims, _Dims,
    _Dims,
)  # fmt: skip
_FAIL = ctypes.CFUNCTYPE(None, c_int, c_char_p)


class BridgeError(RuntimeError):
    """The native bridge cannot be used (not built, or rejected by this ONNX Runtime)."""


def library_path() -> str | None:
    """The compiled bridge's file, or None if the package was installed without it."""
    spec = importlib.util.find_spec(LIBRARY)
    origin = spec.origin if spec else None
    return os.path.realpath(origin) if origin and os.path.isfile(origin) else None


def _shape(dims, ranks, i: int) -> tuple[int, ...]:
    return tuple(dims[i * MAX_RANK : i * MAX_RANK + ranks[i]])


def _view(address: int | None, shape: tuple[int, ...]) -> np.ndarray:
    """A float32 numpy view of ORT's buffer at `address` (no copy)."""
    count = math.prod(shape)
    if count == 0 or not address:
        return np.empty(shape, np.float32)
    return np.frombuffer((ctypes.c_float * count).from_address(address), np.float32).reshape(shape)


def _declared_attrs(spec) -> str:
    """The attributes as rtd_declare_op reads them: `name`, or `name=value` for an optional one
    (a node that omits it gets the value)."""
    opt = spec.optional_attrs
    return ",".join(f"{a}={opt[a]}" if a in opt else a for a in spec.attrs)


class _Bridge:
    """The loaded library, its declared ops (index = id) and the callbacks it holds."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.lib = ctypes.CDLL(path)  # ORT's dlopen of the same file shares these globals
        self.lib.rtd_declare_op.argtypes = [c_char_p, c_int, c_int, c_char_p]
        self.lib.rtd_declare_op.restype = c_int
        self.lib.rtd_op_count.restype = c_int
        self.kernels: list[FastKernel] = []
        if self.lib.rtd_op_count() == 0:  # the library keeps its ops for the process
            for kernel in KERNELS.values():
                spec = kernel.spec
                op_id = self.lib.rtd_declare_op(
                    spec.name.encode(), len(spec.inputs), len(spec.outputs),
                    _declared_attrs(spec).encode(),
                )  # fmt: skip
                if op_id != len(self.kernels):
                    raise BridgeError(f"the native bridge cannot declare op {spec.name}")
                self.kernels.append(kernel)
        elif self.lib.rtd_op_count() == len(KERNELS):  # declared by an earlier load
            self.kernels = list(KERNELS.values())
        else:  # an earlier load failed part-way: some op would silently run its ONNX body
            raise BridgeError("the native bridge holds only some of the ops")
        # Kept referenced for the life of the process: the library calls them.
        self.callbacks = (_SHAPE(self._shapes), _COMPUTE(self._compute), _FAIL(self._fail))
        self.lib.rtd_set_callbacks(*self.callbacks)

    def _attrs(self, kernel: FastKernel, attrs) -> dict[str, int]:
        return {name: int(attrs[i]) for i, name in enumerate(kernel.spec.attrs)}

    def _shapes(self, op, n_in, in_dims, in_rank, attrs, out_dims, out_rank) -> int:
        kernel = self.kernels[op]
        try:
            shapes = [_shape(in_dims, in_rank, i) for i in range(n_in)]
            values = self._attrs(kernel, attrs)
            kernel.spec.validate_call(shapes, values)
            for o, shape in enumerate(kernel.spec.output_shapes(shapes, values)):
                if len(shape) > MAX_RANK:
                    raise ValueError(f"output {o} has rank {len(shape)} > {MAX_RANK}")
                out_rank[o] = len(shape)
                for d, size in enumerate(shape):
                    out_dims[o * MAX_RANK + d] = int(size)
            return 0
        except BaseException as exc:  # leaving the callback would abort the process
            record_failure(exc, kernel.name)
            return 1

    def _compute(
        self, op, n_in, in_data, in_dims, in_rank, n_out, out_data, out_dims, out_rank, attrs
    ) -> int:
        kernel = self.kernels[op]
        outs: list[np.ndarray] = []
        try:
            CALLS[kernel.name] += 1
            outs = [_view(out_data[o], _shape(out_dims, out_rank, o)) for o in range(n_out)]
            inputs = [_view(in_data[i], _shape(in_dims, in_rank, i)) for i in range(n_in)]
            kernel.compute(inputs, outs, self._attrs(kernel, attrs))
            return 0
        except BaseException as exc:  # leaving the callback would abort the process
            record_failure(exc, kernel.name)
            try:
                for out in outs:
                    out.fill(np.nan)
            except BaseException:
                pass
            return 1

    def _fail(self, op, message) -> None:
        try:
            name = self.kernels[op].name if 0 <= op < len(self.kernels) else f"op {op}"
            record_failure(RuntimeError((message or b"").decode(errors="replace")), name)
        except BaseException:
            pass


_bridge: _Bridge | None = None


def bridge() -> _Bridge:
    """The loaded bridge (loaded on first use); BridgeError if it was not built."""
    global _bridge
    if _bridge is None:
        path = library_path()
        if path is None:
            raise BridgeError(
                f"{LIBRARY} was not built (no C compiler when the package was installed?)"
            )
        _bridge = _Bridge(path)
    return _bridge


def unavailable_reason() -> str | None:
    """Why the native bridge cannot be used (None: it loads)."""
    try:
        bridge()
        return None
    except (BridgeError, OSError) as exc:
        return str(exc)


def available() -> bool:
    """True if the native bridge was built and loads."""
    return unavailable_reason() is None


def register(options: ort.SessionOptions) -> None:
    """Make sessions created with `options` run the rtdenoise ops through the native bridge."""
    options.register_custom_ops_library(bridge().path)
