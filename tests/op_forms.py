"""Run a custom op in every form: torch reference, ORT portable (function body), ORT with the
fast kernel registered (through the native bridge, the default, and through
onnxruntime-extensions), and the fast kernel called directly. Shared by the op tests.

Tolerance: max |a - b| / max(1, max |ref|) <= RTOL (float32; different summation order).
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
from rtdenoise.runtime.kernels import KERNELS

RTOL = 1e-4


def rel_err(a: np.ndarray, ref: np.ndarray) -> float:
    return float(np.abs(a - ref).max() / max(1.0, float(np.abs(ref).max())))


@functools.cache
def session(op: str, attrs: tuple, bridge: str) -> ort.InferenceSession:
    """ORT session for a single-op model with every dim dynamic (cached per op/attrs/path);
    the fast kernel registered through `bridge` ("native", "extensions"), or none ("")."""
    model = eops.single_op_model(op, None, dict(attrs))
    so = ort.SessionOptions()
    if bridge:
        assert fast_bridge.register_fast_kernels(so, bridge) == bridge
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
    return outs


def assert_forms_agree(outs: dict[str, np.ndarray], expected: np.ndarray | None = None) -> None:
    """Every form has the reference's shape and dtype, is finite and within RTOL of `expected`
    (default: the torch form)."""
    ref = outs["torch"] if expected is None else expected
    for form, out in outs.items():
        assert out.shape == ref.shape and out.dtype == np.float32, form
        assert np.isfinite(out).all(), form
        assert rel_err(out, ref) <= RTOL, (form, rel_err(out, ref))
