"""Benchmark one custom op in its forms, measured side by side in one run.

`bench_op("KernelApply")` times (median ms over `repeats`): the fast kernel called directly,
ONNX Runtime with the fast kernels registered (single-op model), ONNX Runtime running the
portable function body, and the torch reference in eager mode, all on the op's
`example_inputs` (rtdenoise.ops). It also reports the largest difference of each form from
the torch reference.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping

import numpy as np

from rtdenoise.ops import get_spec

FORMS = ("numba", "ort_fast", "ort_portable", "torch")


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
    attrs: Mapping[str, int] | None = None,
    threads: int = 0,
    seed: int = 0,
    tune_allocator: bool = False,
    inputs: list[np.ndarray] | None = None,
) -> dict:
    """Median milliseconds per call of every form of `op_name` on an (N, C, H, W) image.

    attrs default to the op's `default_attrs`; `inputs` (optional) replaces the spec's
    example inputs (e.g. the tensors a model really passes); threads sets ORT intra-op threads,
    numba's and torch's (0 = library default); tune_allocator first applies the process-wide
    runtime.memory.tune_allocator(). Returns {"op", "shape", "attrs", "ms": {form: ms},
    "max_abs_diff": {form: vs torch}}.
    """
    import numba
    import onnxruntime as ort
    import torch

    from rtdenoise.models.ops import TORCH_OPS
    from rtdenoise.runtime import bridge
    from rtdenoise.runtime.kernels import KERNELS
    from rtdenoise.runtime.memory import tune_allocator
    from rtdenoise.runtime.session import ALLOW_SPINNING

    from .ops import single_op_model

    if tune_allocator:
        tune_allocator()
    spec = get_spec(op_name)
    attrs = dict(spec.default_attrs if attrs is None else attrs)
    if inputs is None:
        inputs = spec.example_inputs(tuple(shape), attrs, np.random.default_rng(seed))
    model = single_op_model(op_name, [list(x.shape) for x in inputs], attrs).SerializeToString()
    feed = dict(zip(spec.input_names, inputs, strict=True))

    def session(fast: bool) -> ort.InferenceSession:
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        if fast:
            bridge.register_fast_kernels(so)
            so.add_session_config_entry(ALLOW_SPINNING, "0")  # as Denoiser runs it
        return ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])

    fast_sess, portable_sess = session(True), session(False)
    kernel, reference = KERNELS[op_name], TORCH_OPS[op_name].reference
    tensors = [torch.from_numpy(x) for x in inputs]
    if threads:
        torch.set_num_threads(threads)
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))

    def first(out) -> np.ndarray:
        return out[0] if isinstance(out, (tuple, list)) else out

    def torch_call() -> np.ndarray:
        with torch.no_grad():
            return first(reference(*tensors, **attrs)).numpy()

    calls: dict[str, Callable[[], np.ndarray]] = {
        "numba": lambda: first(kernel(*inputs, **attrs)),
        "ort_fast": lambda: fast_sess.run(None, feed)[0],
        "ort_portable": lambda: portable_sess.run(None, feed)[0],
        "torch": torch_call,
    }
    outputs: dict[str, np.ndarray] = {}

    def keep(form: str) -> Callable[[], None]:
        def call() -> None:
            outputs[form] = calls[form]()

        return call

    ms = {form: _median_ms(keep(form), repeats) for form in FORMS}
    ref = outputs["torch"]
    diffs = {f: float(np.abs(outputs[f] - ref).max()) for f in FORMS if f != "torch"}
    return {"op": op_name, "shape": tuple(shape), "attrs": attrs, "ms": ms, "max_abs_diff": diffs}
