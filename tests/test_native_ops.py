"""The C++ custom-op library rtdenoise_ops (runtime/bridge/native_ops/, `native-cpp`): built by
the install, chosen by default for a model whose every custom op it holds (every shipped
demo), forced off by RTDENOISE_NATIVE_OPS=0 or an explicit
bridge, the same numbers as the numba kernels over a demo's frames with state, errors as ONNX
Runtime statuses naming the op and the cause, no Python inside. (Each op against its other
forms: test_ops_three_forms.py, test_op_specs.py.) Skipped, with the reason, only where the
library was not built."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import helper

from rtdenoise.export import ops as eops
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.runtime.errors import InputError
from rtdenoise.shipped import demo_model, sample_sequences

AFN_OPS = {"TemporalAccumulation", "SoftmaxKernelApply", "AdaptiveFusion"}


@pytest.fixture(autouse=True)
def built(monkeypatch):
    reason = native_cpp.unavailable_reason()
    if reason is not None:
        pytest.skip(f"the C++ library rtdenoise_ops was not built: {reason}")
    monkeypatch.delenv(native_cpp.ENV_SWITCH, raising=False)


def cpp_session(model) -> ort.InferenceSession:
    so = ort.SessionOptions()
    so.log_severity_level = 3  # the expected failures below: no error log on stderr
    ops = [n.op_type for n in model.graph.node if n.domain == "rtdenoise"]
    assert fast_bridge.register_fast_kernels(so, "native-cpp", ops) == "native-cpp"
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def demo_ops(family: str) -> set[str]:
    """The rtdenoise op types of a demo's graph."""
    model = onnx.load(demo_model(family, ".onnx"))
    return {n.op_type for n in model.graph.node if n.domain == "rtdenoise"}


def test_chosen_for_afn_and_only_where_it_holds_every_op(monkeypatch):
    assert AFN_OPS <= native_cpp.covered_ops()
    den = Denoiser("demo:afn")
    assert den.bridge == "native-cpp" and den.fast_kernels
    assert Denoiser("demo:wskp").bridge == "native-cpp"
    assert Denoiser("demo:nbg").bridge == "native-cpp"
    assert Denoiser("demo:affinity").bridge == "native-cpp"  # numba installed or not
    for family in ("affinity", "crossreg"):  # every op of every demo is held
        assert demo_ops(family) <= native_cpp.covered_ops(), family
    assert Denoiser("demo:crossreg").bridge == "native-cpp"
    assert Denoiser("demo:affinity", fast_kernels="native").bridge == "native"  # numba, asked
    assert Denoiser("demo:afn", fast_kernels="native").bridge == "native"  # numba, asked for
    held = native_cpp.covered_ops() - {"AffinityFilter", "TemporalAffinityFilter"}
    monkeypatch.setattr(native_cpp, "covered_ops", lambda: held)  # a library without them
    assert Denoiser("demo:affinity").bridge == "native"
    with pytest.raises(InputError, match="lacks AffinityFilter, TemporalAffinityFilter"):
        Denoiser("demo:affinity", fast_kernels="native-cpp")
    monkeypatch.undo()
    monkeypatch.setenv(native_cpp.ENV_SWITCH, "0")
    assert Denoiser("demo:afn").bridge == "native"
    assert fast_bridge.choose_bridge(AFN_OPS) == "native"
    monkeypatch.delenv(native_cpp.ENV_SWITCH)
    assert fast_bridge.choose_bridge(AFN_OPS) == "native-cpp"
    assert fast_bridge.choose_bridge(None) == "native"  # ops unknown: the numba bridge


@pytest.mark.parametrize("family", ["afn", "wskp", "nbg"])
def test_demo_native_cpp_matches_numba_over_eight_frames_with_state(family):
    """The committed sequence through the demo, state fed back, a reset at frame 5: the C++
    path and the numba path agree within 1e-5 on every frame and in the state."""
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame

    cpp = Denoiser(f"demo:{family}", fast_kernels="native-cpp")
    numba = Denoiser(f"demo:{family}", fast_kernels="native")
    assert cpp.bridge == "native-cpp"
    frames = [read_frame(p).buffers for p in find_frames(sample_sequences()[0])][:8]
    assert len(frames) == 8
    worst = 0.0
    for t, frame in enumerate(frames):
        if t == 5:
            cpp.reset()
            numba.reset()
        a, b = cpp.process(frame), numba.process(frame)
        worst = max(worst, float(np.abs(a - b).max() / max(1.0, float(np.abs(b).max()))))
    assert worst <= 1e-5, worst
    for spec in cpp.state_specs:  # the history both carry forward
        a, b = cpp.state_value(spec.name), numba.state_value(spec.name)
        assert float(np.abs(a - b).max()) <= 1e-5 * max(1.0, float(np.abs(b).max())), spec.name


@pytest.mark.parametrize("family", ["affinity", "crossreg"])
def test_demo_affinity_and_crossreg_native_cpp_match_numba_with_state(family):
    """demo:affinity (Isik21) and demo:crossreg (Choi24, learning online) on six 64x64 frames
    of the committed sequence, state fed back, a reset at frame 4: the C++ path and the numba
    path agree within 1e-5 on every frame and in every state (crossreg's weights and Adam
    moments included)."""
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame
    from rtdenoise.runtime.sequences.samples import sample_features_of, samples_from_buffers

    cpp = Denoiser(f"demo:{family}", fast_kernels="native-cpp")
    numba = Denoiser(f"demo:{family}", fast_kernels="native")
    assert cpp.bridge == "native-cpp" and numba.bridge == "native"
    if family == "crossreg":
        assert cpp.online is not None  # it learns while it runs (the default)
    paths = find_frames(sample_sequences()[0])[:6]
    frames = [dict(read_frame(p).buffers) for p in paths]
    if "samples" in cpp.required_buffers:  # affinity's per-sample input, from the buffers
        for f in frames:
            f["samples"] = samples_from_buffers(f, sample_features_of(cpp.config))
    worst = 0.0
    for t, frame in enumerate(frames):
        if t == 4:
            cpp.reset()
            numba.reset()
        a, b = cpp.process(frame), numba.process(frame)
        assert a.shape == (3, 64, 64)
        worst = max(worst, float(np.abs(a - b).max() / max(1.0, float(np.abs(b).max()))))
    assert worst <= 1e-5, worst
    for spec in cpp.state_specs:
        a, b = cpp.state_value(spec.name), numba.state_value(spec.name)
        assert float(np.abs(a - b).max()) <= 1e-5 * max(1.0, float(np.abs(b).max())), spec.name
    if family == "crossreg":
        assert float(cpp.state_value("adam_t").ravel()[0]) > 0  # it did learn


def test_threads_give_the_same_bits_and_are_restored():
    model = eops.single_op_model(
        "SoftmaxKernelApply", None, {"kernel_size": 7, "dilation": 2}, with_function=False
    )
    sess = cpp_session(model)
    rng = np.random.default_rng(0)
    feed = {
        "image": rng.random((1, 3, 67, 91), dtype=np.float32),
        "logits": rng.standard_normal((1, 49, 67, 91), dtype=np.float32),
    }
    outs = []
    for team in (1, 2, 3, None):
        with fast_bridge.kernel_threads("native-cpp", team):
            outs.append(sess.run(None, feed)[0])
    for out in outs[1:]:
        np.testing.assert_array_equal(out, outs[0])
    lib = native_cpp._library()
    assert lib.rtdenoise_ops_set_threads(0) == 0  # restored to the default after each


def test_filters_flush_denormals_ops_kept_to_the_bit_keep_them_and_the_host_mode_is_kept():
    """Every op but the to-the-bit ones (Reproject, TemporalAccumulation, SvgfReproject) runs
    with denormals flushed to zero, on the caller's thread and on the workers (a denormal
    operand costs Intel cores a microcode assist each: CrossBilateralFilter ran 17x slower);
    the host thread's own mode is left as it was."""
    from rtdenoise.runtime.kernels import KERNELS

    denormal = np.float32(1e-39)
    image = np.full((1, 3, 96, 96), denormal, np.float32)
    kernel = np.full((1, 9, 96, 96), 1 / 9, np.float32)
    assert (KERNELS["KernelApply"](image, kernel, 3, 1) > 0).all()  # numba keeps them
    sess = cpp_session(
        eops.single_op_model(
            "KernelApply", None, {"kernel_size": 3, "dilation": 1}, with_function=False
        )
    )
    for team in (1, 2):
        with fast_bridge.kernel_threads("native-cpp", team):
            assert (sess.run(None, {"image": image, "kernel": kernel})[0] == 0).all(), team
    reproject = cpp_session(
        eops.single_op_model("Reproject", None, {"nearest": 0}, with_function=False)
    )
    motion = np.zeros((1, 2, 96, 96), np.float32)
    for team in (1, 2):
        with fast_bridge.kernel_threads("native-cpp", team):
            out = reproject.run(None, {"previous": image, "motion": motion})[0]
        np.testing.assert_array_equal(out, image)  # a still frame: the same denormals
    assert np.float32(1e-38) * np.float32(0.01) > 0  # this thread still computes denormals


@pytest.mark.parametrize(
    "feed, message",
    [
        (
            {"image": np.zeros((1, 3, 5, 5), np.float32), "kernel": np.zeros((1, 25, 5, 5))},
            "rtdenoise_ops: KernelApply: kernel has 25 channels; expected kernel_size^2 = 9",
        ),
        (
            {"image": np.zeros((1, 3, 5, 5), np.float32), "kernel": np.zeros((1, 9, 5, 6))},
            "rtdenoise_ops: KernelApply: kernel has shape (1, 9, 5, 6); expected N, H, W",
        ),
    ],
)
def test_a_call_that_breaks_the_spec_is_an_ort_error_naming_op_and_cause(feed, message):
    sess = cpp_session(
        eops.single_op_model(
            "KernelApply", None, {"kernel_size": 3, "dilation": 1}, with_function=False
        )
    )
    feed = {k: v.astype(np.float32) for k, v in feed.items()}
    with pytest.raises(Exception, match=re.escape(message)):
        sess.run(None, feed)
    ok = {"image": np.ones((1, 3, 5, 5), np.float32), "kernel": np.ones((1, 9, 5, 5), np.float32)}
    np.testing.assert_allclose(sess.run(None, ok)[0], 9.0)  # the session still runs


def test_a_node_without_its_attribute_is_refused_at_load():
    model = eops.single_op_model(
        "KernelApply", None, {"kernel_size": 3, "dilation": 1}, with_function=False
    )
    node = model.graph.node[0]
    del node.attribute[:]
    node.attribute.extend([helper.make_attribute("kernel_size", 3)])
    with pytest.raises(Exception, match="KernelApply: the node has no int attribute 'dilation'"):
        cpp_session(model)


def test_kernel_fusion_non_finite_logits_give_nan_like_numba():
    from rtdenoise.runtime.kernels import KERNELS

    sess = cpp_session(eops.single_op_model("KernelFusion", None, {}, with_function=False))
    rng = np.random.default_rng(1)
    images = rng.random((1, 12, 6, 7), dtype=np.float32)
    logits = rng.standard_normal((1, 4, 6, 7), dtype=np.float32)
    logits[0, 2, 3, 4] = np.inf
    out = sess.run(None, {"images": images, "logits": logits})[0]
    assert np.isnan(out).all()
    assert np.isnan(KERNELS["KernelFusion"](images, logits)).all()
    images[0, 5, 1, 1] = np.nan  # a NaN image pixel: NaN out, as numba's check after the run
    logits[0, 2, 3, 4] = 0.0
    out = sess.run(None, {"images": images, "logits": logits})[0]
    assert np.isnan(out).all() and np.isnan(KERNELS["KernelFusion"](images, logits)).all()


@pytest.mark.parametrize("op", ["AffinityFilter", "TemporalAffinityFilter", "CrossRegression"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_inputs_give_all_nan_like_numba(op, bad):
    """As the numba drivers (nan_on_nonfinite over every input, docs/reliability.md): a NaN or
    Inf in any pixel buffer fills every output with NaN; finite inputs give finite outputs."""
    from rtdenoise.ops import get_spec
    from rtdenoise.runtime.kernels import KERNELS

    spec = get_spec(op)
    attrs = spec.attr_sets()[0]
    sess = cpp_session(eops.single_op_model(op, None, attrs, with_function=False))
    inputs = spec.example_inputs((1, 3, 12, 10), attrs, np.random.default_rng(2))
    names = spec.input_names
    assert all(np.isfinite(o).all() for o in sess.run(None, dict(zip(names, inputs, strict=True))))
    for i, a in enumerate(inputs):
        if a.ndim == 0:  # a kernel size: not a pixel buffer
            continue
        x = [b.copy() for b in inputs]
        x[i].flat[7] = bad
        outs = sess.run(None, dict(zip(names, x, strict=True)))
        numba = KERNELS[op](*x, **attrs)
        for o, n in zip(outs, numba if isinstance(numba, tuple) else (numba,), strict=True):
            assert np.isnan(o).all() and np.isnan(n).all(), (op, i)


@pytest.mark.parametrize("size, message", [(4.0, "got 4"), (2.5, "got 2.5"), (65.0, "got 65")])
def test_a_bad_kernel_size_input_is_an_ort_error_naming_op_and_cause(size, message):
    from rtdenoise.ops import get_spec

    spec = get_spec("AffinityFilter")
    model = eops.single_op_model("AffinityFilter", None, {"dilation": 1}, with_function=False)
    sess = cpp_session(model)
    inputs = spec.example_inputs((1, 3, 8, 9), {"dilation": 1}, np.random.default_rng(0))
    feed = dict(zip(spec.input_names, inputs, strict=True))
    feed["kernel_size"] = np.array(size, np.float32)
    cause = "AffinityFilter: kernel size must be an odd integer in [1, 63], " + message
    with pytest.raises(Exception, match=re.escape("rtdenoise_ops: " + cause)):
        sess.run(None, feed)
    feed["image"][0, 0, 0, 0] = np.nan  # the finiteness guard first, as the numba driver
    assert np.isnan(sess.run(None, feed)[0]).all()


@pytest.mark.parametrize("nearest", [0, 1])
def test_empty_inputs_give_empty_outputs(nearest):
    model = eops.single_op_model("Reproject", None, {"nearest": nearest}, with_function=False)
    out = cpp_session(model).run(
        None,
        {
            "previous": np.zeros((1, 3, 0, 4), np.float32),
            "motion": np.zeros((1, 2, 0, 4), np.float32),
        },
    )[0]
    assert out.shape == (1, 3, 0, 4)


def test_the_library_holds_no_python():
    """A plain shared library: it exports RegisterCustomOps and needs no libpython symbol."""
    path = native_cpp.library_path()
    if sys.platform != "linux":
        pytest.skip("checked with nm on Linux")
    symbols = subprocess.run(["nm", "-D", path], capture_output=True, text=True, check=True).stdout
    defined = {line.split()[-1] for line in symbols.splitlines() if " T " in line}
    assert "RegisterCustomOps" in defined
    undefined = [line.split()[-1] for line in symbols.splitlines() if line.split()[0] == "U"]
    assert not [s for s in undefined if s.startswith("Py")], undefined


def test_afn_runs_on_it_without_numba(tmp_path):
    """With numba blocked the runtime still runs demo:afn on the C++ kernels."""
    code = """
import sys
sys.modules["numba"] = None
sys.modules["torch"] = None
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
den = Denoiser("demo:afn")
frames = synthetic_frames(den.required_buffers, 2, 40, 56, seed=1)
outs = [den.process(f) for f in frames]
assert all(o.shape == (3, 40, 56) for o in outs)
assert not any(m == "numba" or m.startswith("numba.") for m in sys.modules if sys.modules[m])
print(den.bridge)
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "native-cpp"
