"""The native custom-op bridge (runtime/bridge/_ort_bridge.c + runtime/bridge/native.py): built
by the install, the default bridge, zero-copy, and every failure a Python exception after the run.
(Agreement of every op with its other forms, on both bridges: test_op_specs.py.)"""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import helper

from rtdenoise.export import ops as eops
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.bridge import native
from rtdenoise.runtime.kernels import KERNELS
from rtdenoise.runtime.kernels.fast_kernel import FastKernel


def native_session(model: onnx.ModelProto) -> ort.InferenceSession:
    so = ort.SessionOptions()
    assert fast_bridge.register_fast_kernels(so, "native") == "native"
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def kernel_apply_model(**attrs: int) -> onnx.ModelProto:
    """One KernelApply node without its function body (it runs only through a bridge), with
    `attrs` in place of the usual kernel_size=3, dilation=1 if given."""
    model = eops.single_op_model(
        "KernelApply", None, {"kernel_size": 3, "dilation": 1}, with_function=False
    )
    if attrs:
        node = model.graph.node[0]
        del node.attribute[:]
        node.attribute.extend(helper.make_attribute(k, v) for k, v in attrs.items())
    return model


def test_the_install_built_it_and_it_is_the_default(monkeypatch):
    """The default of the numba kernels (the C++ library, where it holds a model's ops, is
    chosen before them: test_native_ops.py)."""
    assert native.library_path() is not None, "pip install did not build the bridge"
    assert native.available() and fast_bridge.default_bridge() == "native"
    monkeypatch.setenv("RTDENOISE_NATIVE_OPS", "0")
    assert Denoiser("demo:wskp").bridge == "native"
    assert Denoiser("demo:wskp", fast_kernels="extensions").bridge == "extensions"
    assert Denoiser("demo:wskp", fast_kernels=False).bridge == ""
    with pytest.raises(Exception, match="fast_kernels='nope'"):
        Denoiser("demo:wskp", fast_kernels="nope")


def test_the_kernel_reads_and_writes_onnxruntimes_own_buffers(monkeypatch):
    """Zero-copy: the arrays the kernel gets are views (no data of their own) on ORT's
    buffers, and the output it fills is the very buffer the run returns."""
    seen: list[tuple[bool, ...]] = []
    original = FastKernel.compute

    def compute(self, inputs, outs, attrs):
        seen.append(tuple(a.flags.owndata for a in (*inputs, *outs)))
        addresses.append(outs[0].ctypes.data)
        return original(self, inputs, outs, attrs)

    addresses: list[int] = []
    monkeypatch.setattr(FastKernel, "compute", compute)
    sess = native_session(kernel_apply_model())
    rng = np.random.default_rng(0)
    image = rng.random((1, 3, 20, 30), dtype=np.float32)
    kernel = rng.random((1, 9, 20, 30), dtype=np.float32)
    given = (image.copy(), kernel.copy())
    binding = sess.io_binding()
    binding.bind_cpu_input("image", image)
    binding.bind_cpu_input("kernel", kernel)
    out = np.zeros((1, 3, 20, 30), np.float32)
    binding.bind_output("output", "cpu", 0, np.float32, out.shape, out.ctypes.data)
    sess.run_with_iobinding(binding)
    assert seen == [(False, False, False)]
    assert addresses == [out.ctypes.data]  # written in place into the bound output
    np.testing.assert_allclose(out, KERNELS["KernelApply"](image, kernel, 3, 1), atol=1e-6)
    assert np.array_equal(image, given[0]) and np.array_equal(kernel, given[1])  # untouched


@pytest.mark.parametrize(
    ("feeds", "message"),
    [
        ({"image": np.ones((1, 3, 8, 8), np.float32), "kernel": np.ones((1, 5, 8, 8), np.float32)},
         "KernelApply failed: ValueError: KernelApply: kernel has 5 channels"),
        ({"image": np.ones((1, 3, 8, 8), np.float32), "kernel": np.ones((1, 9, 8, 7), np.float32)},
         "KernelApply failed: ValueError"),
    ],
)  # fmt: skip
def test_a_call_that_breaks_the_spec_is_a_python_error(feeds, message):
    sess = native_session(kernel_apply_model())
    with pytest.raises(fast_bridge.KernelError, match=message):
        with fast_bridge.raise_kernel_errors():
            sess.run(None, feeds)
    with fast_bridge.raise_kernel_errors():  # the session still works afterwards
        sess.run(None, {"image": feeds["image"], "kernel": np.ones((1, 9, 8, 8), np.float32)})


def test_a_node_without_a_declared_attribute_is_a_python_error():
    sess = native_session(kernel_apply_model(kernel_size=3))  # no dilation
    ones = np.ones((1, 9, 8, 8), np.float32)
    feeds = {"image": ones[:, :3].copy(), "kernel": ones}
    with pytest.raises(fast_bridge.KernelError, match="attribute is missing"):
        with fast_bridge.raise_kernel_errors():
            sess.run(None, feeds)


def test_without_the_built_bridge_the_kernels_fall_back_with_one_warning(monkeypatch):
    monkeypatch.setenv("RTDENOISE_NATIVE_OPS", "0")  # the numba kernels' bridges, not the C++
    monkeypatch.setattr(native, "_bridge", None)
    monkeypatch.setattr(native, "library_path", lambda: None)
    monkeypatch.setattr(fast_bridge, "_fallback_warned", False)
    with pytest.warns(RuntimeWarning, match="native custom-op bridge unavailable.*was not built"):
        den = Denoiser("demo:wskp")
    assert den.bridge == "extensions" and den.fast_kernels
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once per process
        assert Denoiser("demo:wskp").bridge == "extensions"
    with pytest.raises(native.BridgeError, match="was not built"):
        Denoiser("demo:wskp", fast_kernels="native")


WITHOUT_EXTENSIONS = """
import os, sys, warnings
os.environ["RTDENOISE_NATIVE_OPS"] = "0"  # the numba kernels' bridges, not the C++ library
sys.modules["onnxruntime_extensions"] = None  # `import onnxruntime_extensions` now fails
import numpy as np
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.bridge import native
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
if sys.argv[1] == "no-native":
    native.library_path = lambda: None
warnings.simplefilter("ignore")
den = Denoiser("demo:wskp")
frames = synthetic_frames(den.required_buffers, 3, 24, 40)
np.save(sys.argv[2], np.stack([den.process(f) for f in frames]))
print(den.bridge or "portable", "onnxruntime_extensions" in sys.modules and
      sys.modules["onnxruntime_extensions"] is not None)
"""


@pytest.mark.parametrize("case", ["native", "no-native"])
def test_without_onnxruntime_extensions(tmp_path, case: str) -> None:
    """The native bridge needs no onnxruntime-extensions: blocked, the default Denoiser still
    runs the fast kernels (the same numbers as here); without the native bridge either, the
    portable bodies run."""
    import subprocess
    import sys

    from rtdenoise.runtime.sequences.synthetic import synthetic_frames

    out = tmp_path / "out.npy"
    proc = subprocess.run(
        [sys.executable, "-c", WITHOUT_EXTENSIONS, case, str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    expected_bridge = "native" if case == "native" else "portable"
    assert proc.stdout.split() == [expected_bridge, "False"]
    den = Denoiser("demo:wskp", fast_kernels="native" if case == "native" else False)
    frames = synthetic_frames(den.required_buffers, 3, 24, 40)
    np.testing.assert_array_equal(np.load(out), np.stack([den.process(f) for f in frames]))
