"""Run a custom op in every form: torch reference, ORT portable (function body), ORT with the
fast kernel registered (through the native bridge, the default, and through
onnxruntime-extensions), the fast kernel called directly, and, for the ops the C++ library
rtdenoise_ops holds where it was built, ORT with that library (`native_cpp`, on a model
without the function body, so that only the library can run it). Shared by the op tests.

Tolerance: max |a - b| / max(1, max |ref|) <= RTOL (float32; different summation order);
the C++ form within NATIVE_RTOL of the numba kernel.
"""

from __future__ import annotations

import functools

import numpy as np
import onnxruntime as ort
import torch

from rtdenoise.export import ops as eops
from rtdenoise.models.ops import TORCH_OPS
from rtdenoise.ops import get_spec
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.runtime.kernels import KERNELS

RTOL = 1e-4
NATIVE_RTOL = 1e-5  # the C++ kernels vs numba's: the same loops in float32


def rel_err(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(a - ref).max() / max(1.0, float(np.abs(ref).max())))


@functools.cache
def session(op: str, attrs: tuple, bridge: str) -> ort.InferenceSession:
    """ORT session for a single-op model with every dim dynamic (cached per op/attrs/path);
    the fast kernel registered through `bridge` ("native", "extensions", "native-cpp": then
    without the function body), or none ("")."""
    cpp = bridge == "native-cpp"
    model = eops.single_op_model(op, None, dict(attrs), with_function=not cpp)
    so = ort.SessionOptions()
    if bridge:
        assert fast_bridge.register_fast_kernels(so, bridge, [op]) == bridge
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def first(out):
    return out[0] if isinstance(out, tuple | list) else out


def all_forms(op: str, inputs: list[np.ndarray], attrs: dict) -> dict[str, np.ndarray]:
    """{form: first output} for torch, ORT portable, ORT fast (the kernel must run) and numba."""
    spec = get_spec(op)
    outs = {}
    with torch.no_grad():
        ref = TORCH_OPS[op].reference(*[torch.from_numpy(x) for x in inputs], **attrs)
        outs["torch"] = first(ref).numpy()
    feed = dict(zip(spec.input_names, inputs, strict=True))
    for name, bridge in (("portable", ""), ("ort_fast", "native"), ("ort_ext", "extensions")):
        before = fast_bridge.CALLS[op]
        outs[name] = session(op, tuple(sorted(attrs.items())), bridge).run(None, feed)[0]
        assert fast_bridge.CALLS[op] - before == (1 if bridge else 0), name
    outs["numba"] = first(KERNELS[op](*inputs, **attrs))
    if native_cpp_holds(op):
        outs["native_cpp"] = session(op, tuple(sorted(attrs.items())), "native-cpp").run(
            None, feed
        )[0]
    return outs


def native_cpp_holds(op: str) -> bool:
    """True where the C++ library was built and holds `op`."""
    return op in native_cpp.covered_ops()


def assert_forms_agree(outs: dict[str, np.ndarray], expected: np.ndarray | None = None) -> None:
    """Every form has the reference's shape and dtype, is finite and within RTOL of `expected`
    (default: the torch form)."""
    ref = outs["torch"] if expected is None else expected
    for form, out in outs.items():
        assert out.shape == ref.shape and out.dtype == np.float32, form
        assert np.isfinite(out).all(), form
        assert rel_err(out, ref) <= RTOL, (form, rel_err(out, ref))
    if "native_cpp" in outs:
        err = rel_err(outs["native_cpp"], outs["numba"])
        assert err <= NATIVE_RTOL, ("native_cpp vs numba", err)
