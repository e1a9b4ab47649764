"""Export pass `export.phase_split`: a narrow K x K 'same' conv becomes a stride-2 conv over
its four output phases + an interleaving ConvTranspose + Slice, with ONNX Runtime's outputs
bit-identical at even and odd sizes; the convs it does not pay for are left alone."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.phase_split import PHASE_SPLIT_DOC, phase_split_convs


def conv_model(
    c_in: int, c_out: int, k: int, activation: str | None = "Sigmoid", **attrs
) -> onnx.ModelProto:
    """x (1, c_in, h, w) -> Conv(k x k, 'same') [-> activation] -> y."""
    rng = np.random.default_rng(c_in * 100 + c_out * 10 + k)
    weight = (rng.standard_normal((c_out, c_in, k, k)) * 0.1).astype(np.float32)
    bias = rng.standard_normal(c_out).astype(np.float32)
    attrs = {"pads": [k // 2] * 4, **attrs}
    conv_out = "c" if activation else "y"
    nodes = [helper.make_node("Conv", ["x", "w", "b"], [conv_out], name="conv", **attrs)]
    if activation:
        nodes.append(helper.make_node(activation, ["c"], ["y"], name="act"))
    graph = helper.make_graph(
        nodes, "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, c_in, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, c_out, "h", "w"])],
        [numpy_helper.from_array(weight, "w"), numpy_helper.from_array(bias, "b")],
    )  # fmt: skip
    graph.value_info.extend(  # as torch.onnx records them
        [
            helper.make_tensor_value_info("w", TensorProto.FLOAT, list(weight.shape)),
            helper.make_tensor_value_info("b", TensorProto.FLOAT, list(bias.shape)),
        ]
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})[0]


@pytest.mark.parametrize("activation", ["Sigmoid", None])
def test_narrow_conv_over_phases_gives_the_same_bits(activation: str | None) -> None:
    model = conv_model(24, 5, 5, activation)
    rng = np.random.default_rng(1)
    inputs = [rng.standard_normal((1, 24, h, w)).astype(np.float32) for h, w in
              ((32, 48), (33, 47), (7, 6), (5, 5))]  # fmt: skip
    before = [run(model, x) for x in inputs]
    assert phase_split_convs(model) == ["conv"]
    onnx.checker.check_model(model, full_check=True)
    conv = next(n for n in model.graph.node if n.op_type == "Conv")
    assert conv.doc_string == PHASE_SPLIT_DOC
    attrs = {a.name: list(a.ints) for a in conv.attribute}
    assert attrs["kernel_shape"] == [6, 6] and attrs["strides"] == [2, 2]
    assert attrs["pads"] == [2, 2, 3, 3]
    order = [n.op_type for n in model.graph.node]
    if activation:  # the activation runs on the phases, next to the conv ORT fuses it into
        assert order.index(activation) < order.index("ConvTranspose")
    assert model.graph.output[0].name == "y"
    for x, want in zip(inputs, before, strict=True):
        got = run(model, x)
        assert got.shape == want.shape
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    ("c_in", "c_out", "k", "attrs"),
    [
        (24, 5, 3, {}),  # 3 x 3 measured slower split
        (24, 6, 5, {}),  # too many outputs
        (8, 5, 5, {}),  # too few inputs
        (24, 5, 5, {"strides": [2, 2]}),
        (24, 5, 5, {"dilations": [2, 2], "pads": [4, 4, 4, 4]}),
        (24, 5, 5, {"pads": [2, 2, 2, 1]}),  # not 'same'
    ],
)
def test_convs_it_does_not_pay_for_stay(c_in: int, c_out: int, k: int, attrs: dict) -> None:
    model = conv_model(c_in, c_out, k, **attrs)
    before = model.SerializeToString()
    assert phase_split_convs(model) == []
    assert model.SerializeToString() == before


def test_a_conv_with_other_readers_keeps_its_activation_after_the_crop() -> None:
    model = conv_model(16, 3, 5, "Relu")
    model.graph.node.append(helper.make_node("Neg", ["c"], ["z"], name="neg"))
    model.graph.output.append(
        helper.make_tensor_value_info("z", TensorProto.FLOAT, [1, 3, "h", "w"])
    )
    x = np.random.default_rng(2).standard_normal((1, 16, 21, 18)).astype(np.float32)
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    before = sess.run(None, {"x": x})
    assert phase_split_convs(model) == ["conv"]
    order = [n.op_type for n in model.graph.node]
    assert order.index("Slice") < order.index("Relu")
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    for got, want in zip(sess.run(None, {"x": x}), before, strict=True):
        np.testing.assert_array_equal(got, want)
