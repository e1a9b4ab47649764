"""Register the fast (numba) kernels with ONNX Runtime through onnxruntime-extensions.

Each `rtdenoise.runtime.kernels.KERNELS` entry becomes a Python custom op
`rtdenoise::<Name>` (float32 inputs and outputs, int64 attributes, all from the op's spec). A
registered op takes precedence over the model-local function body of the same name
(docs/architecture.md, "The three forms").

Pitfalls handled here (research-notes "Custom ops"):
- ops must be declared before `register_custom_ops_library`: they are declared at import;
- the library's default result hook converts every output with `.flatten().tolist()`
  (~180 ms per 720p call); `_array_hook` hands the ndarray back instead. It replaces a
  library-internal function, so it is installed only for the versions checked to speak its
  protocol (`HOOK_VERSIONS`: their `_ocos.py` are identical, and the op, demo-model and
  torch-free runtime tests passed on each);
- every declared attribute must be present on the node (the exporter writes them all);
- inputs and outputs are copied on every call; at 720p KernelApply's 49-channel kernel is
  180 MB, and glibc serves such blocks with fresh mmaps that page-fault on every call.
  `tune_allocator()` (opt-in, process-wide) keeps them in the heap instead.
No torch here.
"""

from __future__ import annotations

import sys
import warnings
from collections import Counter

import numpy as np
import onnxruntime as ort

from rtdenoise.ops import DOMAIN

from .kernels import KERNELS, FastKernel
from .memory import tune_allocator  # noqa: F401  (re-exported)


def _import_extensions_without_torch():
    """Import onnxruntime-extensions with torch hidden: 0.15.2 imports torch when installed
    (for a Whisper converter, `cvt.py`), ~5 s and ~1 GB the runtime must not pay."""
    hide = "torch" not in sys.modules
    if hide:
        sys.modules["torch"] = None  # type: ignore[assignment]  # `import torch` -> ImportError
    try:
        import onnxruntime_extensions
        from onnxruntime_extensions import _ocos
    finally:
        if hide and sys.modules.get("torch", 0) is None:
            del sys.modules["torch"]
    return onnxruntime_extensions, _ocos


onnxruntime_extensions, _ortx_ocos = _import_extensions_without_torch()
PyCustomOpDef = onnxruntime_extensions.PyCustomOpDef
get_library_path = onnxruntime_extensions.get_library_path
onnx_op = onnxruntime_extensions.onnx_op

# The onnxruntime-extensions versions whose hook protocol `_array_hook` follows.
HOOK_VERSIONS = ("0.15.0", "0.15.2")

FAST_OPS: tuple[str, ...] = tuple(KERNELS)

# Calls per op through ORT (tests use it to prove the fast kernel ran).
CALLS: Counter[str] = Counter()

_hook_installed = False


def _array_hook(k_id: int, feed: list, attributes: dict) -> tuple:
    """Result hook: like onnxruntime_extensions._ocos._on_pyop_invocation, returning arrays.

    The C++ side receives (k_id, shape_0, values_0, shape_1, values_1, ...); it accepts a
    numpy array for values, which skips the per-element Python list round trip.
    """
    opdef = _ortx_ocos.Opdef._odlist.get(k_id)
    if opdef is None:
        raise RuntimeError(f"no Python custom op with id {k_id}; was it declared with @onnx_op?")
    rv = opdef.body(*feed, **opdef.cast_attributes(attributes))
    results = rv if isinstance(rv, tuple) else (rv,)
    out: list = []
    for r in results:
        r = np.asarray(r)
        out.append(r.shape)
        if r.dtype.kind in "OUS":  # string tensors keep the library's list protocol
            out.append(r.flatten().tolist())
        else:
            out.append(np.ascontiguousarray(r))
    return (k_id, *out)


def install_array_hook() -> bool:
    """Install `_array_hook` (idempotent). Returns False, with a warning, on another version."""
    global _hook_installed
    if _hook_installed:
        return True
    if onnxruntime_extensions.__version__ not in HOOK_VERSIONS:
        warnings.warn(
            f"onnxruntime-extensions {onnxruntime_extensions.__version__} is none of "
            f"{', '.join(HOOK_VERSIONS)}: "
            "keeping its default result hook (correct but ~100x slower per call)",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    PyCustomOpDef.install_hooker(_array_hook)
    _hook_installed = True
    return True


def hook_installed() -> bool:
    """True when the array-returning hook is the active one."""
    return _hook_installed


def _declare(kernel: FastKernel) -> None:
    def body(*inputs, **attrs):
        CALLS[kernel.name] += 1
        return kernel(*inputs, **attrs)

    body.__name__ = f"rtdenoise_{kernel.name}"
    onnx_op(
        op_type=f"{DOMAIN}::{kernel.name}",
        inputs=[PyCustomOpDef.dt_float] * len(kernel.spec.inputs),
        outputs=[PyCustomOpDef.dt_float] * len(kernel.spec.outputs),
        attrs={a: PyCustomOpDef.dt_int64 for a in kernel.spec.attrs},
    )(body)


# Declared once, at import, before any session registers the library.
for _kernel in KERNELS.values():
    _declare(_kernel)


def register_fast_kernels(so: ort.SessionOptions) -> None:
    """Make sessions created with `so` run the rtdenoise ops with the numba kernels."""
    install_array_hook()
    so.register_custom_ops_library(get_library_path())


__all__ = [
    "CALLS",
    "FAST_OPS",
    "hook_installed",
    "install_array_hook",
    "register_fast_kernels",
    "tune_allocator",
]
