"""AVX-512 conv forms under If(layout.nchwc16): the export pass `export.layout_forms` and the
runtime's choice (`runtime/layout.py`). Either form gives the original's outputs (the row
phases exactly, at even and odd heights), ORT inlines the chosen branch at load (no If is left
to run), the runtime writes the flag for the CPU, and the shipped demo:nbg agrees with itself
across the two forms over frames with state fed back."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.layout_forms import LAYOUT_FLAG, layout_forms
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.layout import ENV, nchwc_block, with_layout
from rtdenoise.runtime.sequences.synthetic import synthetic_frames


def guide_net(seed: int = 0) -> onnx.ModelProto:
    """nbg's GuideNet in small: 13 channels zero-padded to 16 -> 32 (5 x 5, leaky ReLU) -> 8
    (5 x 5, sigmoid), at the input's size."""
    rng = np.random.default_rng(seed)
    w1 = rng.normal(0, 0.1, (32, 16, 5, 5)).astype(np.float32)
    w1[:, 13:] = 0  # the padded channels' weights, as conv_widths.pad_conv_inputs writes them
    inits = {
        "w1": w1,
        "b1": rng.normal(0, 0.1, 32).astype(np.float32),
        "w2": rng.normal(0, 0.1, (8, 32, 5, 5)).astype(np.float32),
        "b2": rng.normal(0, 0.1, 8).astype(np.float32),
        "count": np.array([3], np.int64),
    }
    nodes = [
        helper.make_node("Shape", ["a"], ["n"], start=0, end=1),
        helper.make_node("Shape", ["a"], ["hw"], start=2),
        helper.make_node("Concat", ["n", "count", "hw"], ["zshape"], axis=0),
        helper.make_node(
            "ConstantOfShape",
            ["zshape"],
            ["zeros"],
            value=helper.make_tensor("value", TensorProto.FLOAT, [1], [0.0]),
        ),
        helper.make_node("Concat", ["a", "b", "zeros"], ["cat"], axis=1, name="cat"),
        helper.make_node("Conv", ["cat", "w1", "b1"], ["c1"], pads=[2] * 4, name="conv1"),
        helper.make_node("LeakyRelu", ["c1"], ["h"], alpha=0.2),
        helper.make_node("Conv", ["h", "w2", "b2"], ["c2"], pads=[2] * 4, name="conv2"),
        helper.make_node("Sigmoid", ["c2"], ["y"]),
    ]
    inputs = [
        helper.make_tensor_value_info("a", TensorProto.FLOAT, [1, 10, "h", "w"]),
        helper.make_tensor_value_info("b", TensorProto.FLOAT, [1, 3, "h", "w"]),
    ]
    out = [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 8, "h", "w"])]
    graph = helper.make_graph(
        nodes, "guide", inputs, out, [numpy_helper.from_array(v, k) for k, v in inits.items()]
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(model: bytes, feed: dict, optimized: Path | None = None) -> np.ndarray:
    so = ort.SessionOptions()
    so.log_severity_level = 3
    if optimized is not None:
        so.optimized_model_filepath = str(optimized)
    session = ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])
    return session.run(None, feed)[0]


def test_pass_wraps_both_convs_and_keeps_the_file_on_the_original_form() -> None:
    proto = guide_net()
    assert layout_forms(proto) == ["row_phases: conv2", "zero_inputs_dropped: conv1"]
    onnx.checker.check_model(proto, full_check=True)
    assert [n.op_type for n in proto.graph.node].count("If") == 2
    assert not any(n.op_type == "Conv" for n in proto.graph.node)  # both under an If
    flag = next(i for i in proto.graph.initializer if i.name == LAYOUT_FLAG)
    assert not numpy_helper.to_array(flag)  # the file keeps the original form


@pytest.mark.parametrize("size", [(24, 20), (23, 17), (1, 6)])
def test_both_forms_give_the_original_outputs(size: tuple[int, int]) -> None:
    """Odd heights too: the row-phase form computes one extra row and drops it."""
    h, w = size
    rng = np.random.default_rng(1)
    feed = {"a": rng.normal(0, 1, (1, 10, h, w)).astype(np.float32),
            "b": rng.normal(0, 1, (1, 3, h, w)).astype(np.float32)}  # fmt: skip
    original = guide_net()
    expected = run(original.SerializeToString(), feed)
    layout_forms(original)
    data = original.SerializeToString()
    for nchwc16 in (False, True):
        got = run(with_layout(data, nchwc16), feed)
        assert got.shape == expected.shape == (1, 8, h, w)
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6)


def test_row_phases_alone_are_exact() -> None:
    """The conv's outputs are the same sums of the same products: bit-identical."""
    rng = np.random.default_rng(2)
    w = rng.normal(0, 0.1, (8, 32, 5, 5)).astype(np.float32)
    b = rng.normal(0, 0.1, 8).astype(np.float32)
    nodes = [helper.make_node("Conv", ["x", "w", "b"], ["c"], pads=[2] * 4, name="conv"),
             helper.make_node("Sigmoid", ["c"], ["y"])]  # fmt: skip
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 32, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 8, "h", "w"])],
        [numpy_helper.from_array(w, "w"), numpy_helper.from_array(b, "b")],
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)
    x = rng.normal(0, 1, (1, 32, 33, 40)).astype(np.float32)
    expected = run(proto.SerializeToString(), {"x": x})
    assert layout_forms(proto) == ["row_phases: conv"]
    got = run(with_layout(proto.SerializeToString(), True), {"x": x})
    np.testing.assert_array_equal(got, expected)


def test_ort_inlines_the_chosen_branch_at_load() -> None:
    """The flag is a constant: ORT's optimiser leaves no If (and for True, the interleave of
    the row phases is there)."""
    proto = guide_net()
    layout_forms(proto)
    data = proto.SerializeToString()
    feed = {"a": np.ones((1, 10, 8, 8), np.float32), "b": np.ones((1, 3, 8, 8), np.float32)}
    with tempfile.TemporaryDirectory() as tmp:
        for nchwc16 in (False, True):
            path = Path(tmp) / f"{nchwc16}.onnx"
            run(with_layout(data, nchwc16), feed, optimized=path)
            ops = {n.op_type for n in onnx.load(path).graph.node}
            assert "If" not in ops
            assert ("Transpose" in ops) == nchwc16


def test_a_model_without_the_flag_is_left_alone() -> None:
    data = guide_net().SerializeToString()
    assert with_layout(data, True) is None
    assert with_layout(b"not a model " + LAYOUT_FLAG.encode(), True) is None


def test_the_block_follows_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV, "8")
    assert nchwc_block() == 8
    monkeypatch.setenv(ENV, "16")
    assert nchwc_block() == 16
    monkeypatch.setenv(ENV, "12")
    with pytest.raises(ValueError, match="expected 8 or 16"):
        nchwc_block()
    with pytest.raises(InputError, match="RTDENOISE_NCHWC_BLOCK='12'"):
        Denoiser("demo:nbg")


def test_shipped_nbg_agrees_across_the_two_forms(monkeypatch: pytest.MonkeyPatch) -> None:
    """demo:nbg carries both forms; each agrees with the other over 8 frames with state fed
    back (the export validates both against PyTorch: test_demo_models), asked for by name or
    through RTDENOISE_NCHWC_BLOCK, and the runtime reports which it loaded."""
    outputs = {}
    for layout in ("plain", "nchwc16"):
        den = Denoiser("demo:nbg", layout=layout)
        assert den.layout == layout
        frames = synthetic_frames(den.required_buffers, 6, 40, 56, seed=3)
        frames += synthetic_frames(den.required_buffers, 2, 41, 57, seed=4)  # odd, a new size
        outputs[layout] = [np.array(den.process(f)) for f in frames]
    for a, b in zip(outputs["plain"], outputs["nchwc16"], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
    for block, layout in ((8, "plain"), (16, "nchwc16")):
        monkeypatch.setenv(ENV, str(block))
        assert Denoiser("demo:nbg").layout == layout
    monkeypatch.delenv(ENV)
    expected = "nchwc16" if nchwc_block() == 16 else "plain"
    assert Denoiser("demo:nbg").layout == expected
    with pytest.raises(InputError, match="layout='avx512'"):
        Denoiser("demo:nbg", layout="avx512")
    assert Denoiser("demo:wskp", layout="nchwc16").layout == ""  # no forms to choose


def test_convs_without_a_cheaper_form_stay() -> None:
    """Left alone: a conv whose output is not a graph input's size (a half-scale layer), one
    with too few taps per output (afn's fusion conv, 16 x 3 x 3), and zero channels that
    another node reads too."""
    rng = np.random.default_rng(4)
    inits: list[onnx.TensorProto] = []

    def conv(name: str, src: str, cout: int, cin: int, k: int) -> onnx.NodeProto:
        w = rng.normal(0, 0.1, (cout, cin, k, k)).astype(np.float32)
        inits.append(numpy_helper.from_array(w, f"{name}.w"))
        inits.append(numpy_helper.from_array(np.zeros(cout, np.float32), f"{name}.b"))
        return helper.make_node(
            "Conv", [src, f"{name}.w", f"{name}.b"], [name], name=name, pads=[k // 2] * 4
        )

    nodes = [
        helper.make_node("AveragePool", ["x"], ["half"], kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("Concat", ["half", "half"], ["half32"], axis=1),
        conv("small", "half32", 8, 32, 5),  # half scale: no graph input has its size
        conv("few", "x", 8, 16, 3),  # 144 taps per output, below MIN_PHASE_TAPS
    ]
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 16, "h", "w"])],
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, None) for n in ("small", "few")],
        inits,
    )
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)
    assert layout_forms(proto) == []
    assert LAYOUT_FLAG not in {i.name for i in proto.graph.initializer}

    shared = guide_net()  # its zero channels are a graph output as well
    shared.graph.output.append(helper.make_tensor_value_info("zeros", TensorProto.FLOAT, None))
    assert layout_forms(shared) == ["row_phases: conv2"]
