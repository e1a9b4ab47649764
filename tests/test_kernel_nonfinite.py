"""NaN/Inf produced inside a model reach the fast kernels as inputs: AffinityFilter,
CrossRegression, KernelFusion and TemporalAffinityFilter used to raise a ZeroDivisionError
inside numba ("SystemError: CPUDispatcher ... returned a result with an exception set") on
every frame. They now give NaN outputs, as the portable bodies do, so the Denoiser's recovery
applies on both paths (issue 27, item 4)."""

from __future__ import annotations

import warnings

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.kernels import KERNELS
from rtdenoise.runtime.kernels.nonfinite import all_finite
from rtdenoise.runtime.sequences.samples import sample_features_of, samples_from_buffers
from rtdenoise.shipped import demo_model

OPS = ["AffinityFilter", "CrossRegression", "KernelFusion", "TemporalAffinityFilter"]


def test_all_finite():
    a = np.ones((3, 5), np.float32)
    assert all_finite(a) and all_finite(np.empty(0, np.float32))
    assert all_finite(np.full(4, 3e38, np.float32))  # the sum overflows: the exact test
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[2, 4] = bad
        assert not all_finite(b)


@pytest.mark.parametrize("name", OPS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_kernel_gives_nan_not_an_exception(name, bad):
    kernel = KERNELS[name]
    attrs = kernel.spec.attr_sets()[0]
    inputs = kernel.spec.example_inputs((1, 2, 12, 10), attrs, np.random.default_rng(1))
    for i, a in enumerate(inputs):
        if a.size < 8:  # a scalar (kernel size): not a pixel buffer
            continue
        x = [b.copy() for b in inputs]
        x[i].flat[7] = bad
        outs = kernel(*x, **attrs)
        for out in outs if isinstance(outs, tuple) else (outs,):
            assert np.isnan(out).all(), (name, i)
    clean = kernel(*inputs, **attrs)  # finite inputs: the kernel itself
    for out in clean if isinstance(clean, tuple) else (clean,):
        assert np.isfinite(out).all()


def nan_weights(model: str, tmp_path) -> str:
    """The demo with its first conv weight all NaN (a diverged checkpoint)."""
    m = onnx.load(demo_model(model, ".onnx"))
    init = next(t for t in m.graph.initializer if len(t.dims) == 4)
    bad = np.full(numpy_helper.to_array(init).shape, np.nan, np.float32)
    init.CopyFrom(numpy_helper.from_array(bad, init.name))
    path = tmp_path / f"{model}_nan.onnx"
    onnx.save(m, path)
    return str(path)


def frame(den: Denoiser, h: int = 24, w: int = 20) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    b = {
        "color": rng.exponential(1.0, (3, h, w)),
        "color_b": rng.exponential(1.0, (3, h, w)),
        "albedo": rng.random((3, h, w)),
        "normal": rng.uniform(-1, 1, (3, h, w)),
        "depth": rng.uniform(1, 10, (1, h, w)),
        "motion": rng.normal(0, 1, (2, h, w)),
    }
    b = {k: v.astype(np.float32) for k, v in b.items()}
    if "samples" in den.required_buffers:
        b["samples"] = samples_from_buffers(b, sample_features_of(den.config))
    return {k: v for k, v in b.items() if k in den.required_buffers or k == "color"}


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "portable"])
@pytest.mark.parametrize("model", ["affinity", "crossreg", "wskp"])
def test_nan_weights_take_the_recovery_on_both_paths(model, fast, tmp_path):
    den = Denoiser(nan_weights(model, tmp_path), fast_kernels=fast, threads=1)
    assert den.fast_kernels is fast
    b = frame(den)
    h, w = b["color"].shape[1:]
    for i in range(3):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # "NaN/Inf state", where it is
            out = den.process(b)  # no exception on either path
        assert out.shape == (3, h, w) and np.isfinite(out).all()
        assert den.last_guard.output_nonfinite > 0
        if i:
            assert den.last_guard.reset == "non-finite output in the previous frame"
