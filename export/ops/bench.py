"""Benchmark one custom op in its forms, measured side by side in one run.

`bench_op("KernelApply")` times (median ms over `repeats`): the numba kernel called
directly, ONNX Runtime with the fast kernels registered (single-op model), ONNX Runtime
running the portable function body, and the torch eager reference. It also reports the
largest difference of each form from the torch reference.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from . import SPECS, single_op_model


def _median_ms(fn: Callable[[], object], repeats: int) -> float:
    fn()  # warm-up (compilation, allocations, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1000.0)


def bench_op(
    op_name: str,
    shape: tuple[int, int, int, int] = (1, 3, 720, 1280),
    repeats: int = 5,
    attrs: dict[str, int] | None = None,
    threads: int = 0,
    seed: int = 0,
    tune_allocator: bool = False,
) -> dict:
    """Median milliseconds per call of every form of `op_name` on an (N, C, H, W) image.

    attrs default to the op's `default_attrs`; threads sets ORT intra-op threads and torch
    threads (0 = library default); tune_allocator first applies the process-wide
    runtime.fastops.tune_allocator(). Returns {"op", "shape", "attrs", "ms": {form: ms},
    "max_abs_diff": {form: vs torch}}.
    """
    import onnxruntime as ort
    import torch

    from rtdenoise.models.ops import OPS as TORCH_OPS
    from rtdenoise.runtime import fastops
    from rtdenoise.runtime.kernels import KERNELS

    if tune_allocator:
        fastops.tune_allocator()
    spec = SPECS[op_name]
    attrs = dict(spec.default_attrs if attrs is None else attrs)
    inputs = spec.example_inputs(tuple(shape), attrs, np.random.default_rng(seed))
    shapes = [list(x.shape) for x in inputs]
    model = single_op_model(op_name, shapes, attrs).SerializeToString()
    feed = dict(zip(spec.inputs, inputs, strict=True))

    def session(fast: bool) -> ort.InferenceSession:
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        if fast:
            fastops.register_fast_kernels(so)
        return ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])

    fast_sess, portable_sess = session(True), session(False)
    kernel = KERNELS[op_name].fn
    reference = TORCH_OPS[op_name][2]
    tensors = [torch.from_numpy(x) for x in inputs]
    if threads:
        torch.set_num_threads(threads)

    outputs: dict[str, np.ndarray] = {}

    def run(form: str, fn: Callable[[], np.ndarray]) -> Callable[[], None]:
        def call() -> None:
            outputs[form] = fn()

        return call

    forms = {
        "numba": run("numba", lambda: kernel(*inputs, **attrs)),
        "ort_fast": run("ort_fast", lambda: fast_sess.run(None, feed)[0]),
        "ort_portable": run("ort_portable", lambda: portable_sess.run(None, feed)[0]),
        "torch": run("torch", lambda: _torch_call(reference, tensors, attrs)),
    }
    ms = {form: _median_ms(fn, repeats) for form, fn in forms.items()}
    ref = outputs["torch"]
    diffs = {f: float(np.abs(outputs[f] - ref).max()) for f in forms if f != "torch"}
    return {"op": op_name, "shape": tuple(shape), "attrs": attrs, "ms": ms, "max_abs_diff": diffs}


def _torch_call(reference, tensors, attrs) -> np.ndarray:
    import torch

    with torch.no_grad():
        return reference(*tensors, **attrs).numpy()
