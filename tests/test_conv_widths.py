"""Export passes of `export.conv_widths`: hidden conv widths and conv inputs zero-padded to a
multiple of 8 (ORT's NCHWc layout) compute the same function, and only provably safe chains
change."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.conv_widths import pad_conv_inputs, pad_conv_widths


def chain(widths: list[int], act: str = "LeakyRelu", bias: bool = False) -> onnx.ModelProto:
    """x (widths[0] channels) -> Conv -> act -> Conv -> act ... -> Conv -> y."""
    rng = np.random.default_rng(0)
    nodes, inits, prev = [], [], "x"
    for k, (cin, cout) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
        weight = rng.normal(size=(cout, cin, 3, 3)).astype(np.float32) / (3 * cin**0.5)
        w = numpy_helper.from_array(weight, f"w{k}")
        inputs = [prev, f"w{k}"]
        inits.append(w)
        if bias:
            inits.append(numpy_helper.from_array(rng.normal(size=cout).astype(np.float32), f"b{k}"))
            inputs.append(f"b{k}")
        last = k == len(widths) - 2
        out = "y" if last else f"c{k}"
        nodes.append(helper.make_node("Conv", inputs, [out], name=f"conv{k}", pads=[1, 1, 1, 1]))
        if not last:
            nodes.append(helper.make_node(act, [out], [f"a{k}"]))
            prev = f"a{k}"
    graph = helper.make_graph(
        nodes,
        "chain",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, widths[0], "H", "W"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, widths[-1], "H", "W"])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)
    model = onnx.shape_inference.infer_shapes(model)  # value_info with the old widths
    for i in inits:  # as torch's exporter writes them: the weights' shapes too
        model.graph.value_info.append(helper.make_tensor_value_info(i.name, i.data_type, i.dims))
    return model


def run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})[0]


@pytest.mark.parametrize("bias", [False, True])
def test_wskp_like_chain_is_padded_and_unchanged(bias: bool) -> None:
    model = chain([10, 14, 14, 14, 12], bias=bias)
    x = np.random.default_rng(1).normal(size=(1, 10, 12, 20)).astype(np.float32)
    before = run(model, x)
    padded = pad_conv_widths(model)
    assert [(old, new) for _, old, new in padded] == [(14, 16)] * 3
    onnx.checker.check_model(model, full_check=True)
    shapes = {i.name: tuple(i.dims) for i in model.graph.initializer}
    assert [shapes[f"w{k}"][:2] for k in range(4)] == [(16, 10), (16, 16), (16, 16), (12, 16)]
    assert not bias or [shapes[f"b{k}"] for k in range(4)] == [(16,), (16,), (16,), (12,)]
    after = run(model, x)  # the same sums in another order (NCHWc): float32 rounding only
    assert np.abs(after - before).max() <= 1e-5 * np.abs(before).max()


def test_unsafe_or_costly_chains_are_left_alone() -> None:
    for model in (
        chain([10, 14, 12], act="Sigmoid"),  # sigmoid(0) = 0.5: the extra channels would count
        chain([3, 4, 3]),  # 4 -> 8 doubles the layer
        chain([10, 16, 12]),  # already a multiple of 8
        chain([10, 14]),  # the conv's output is the graph's
    ):
        before = model.SerializeToString()
        assert pad_conv_widths(model) == []
        assert model.SerializeToString() == before


def unet_level(resize_sizes: bool = False) -> onnx.ModelProto:
    """x (14 channels, a Concat of 8 + 6) -> Conv 16 -> Relu (skip) -> AveragePool -> Conv 12 ->
    Relu -> Resize x2 -> Concat [up (12), skip (16)] -> Conv 16 -> y: AFN's level pattern with
    a 12-wide half scale and a 14-channel input."""
    rng = np.random.default_rng(2)

    def weight(name: str, c_out: int, c_in: int) -> onnx.TensorProto:
        w = rng.normal(size=(c_out, c_in, 3, 3)).astype(np.float32) / (3 * c_in**0.5)
        return numpy_helper.from_array(w, name)

    resize_inputs = ["h1", "", "scales"] if not resize_sizes else ["h1", "", "", "sizes"]
    nodes = [
        helper.make_node("Concat", ["a", "b"], ["x"], name="input_cat", axis=1),
        helper.make_node("Conv", ["x", "w0"], ["c0"], name="enc0", pads=[1] * 4),
        helper.make_node("Relu", ["c0"], ["skip"]),
        helper.make_node("AveragePool", ["skip"], ["p"], kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("Conv", ["p", "w1", "b1"], ["c1"], name="enc1", pads=[1] * 4),
        helper.make_node("Relu", ["c1"], ["h1"]),
        helper.make_node("Resize", resize_inputs, ["up"], mode="nearest"),
        helper.make_node("Concat", ["up", "skip"], ["cat"], name="skip_cat", axis=1),
        helper.make_node("Conv", ["cat", "w2"], ["y"], name="dec0", pads=[1] * 4),
    ]
    inits = [
        weight("w0", 16, 14),
        weight("w1", 12, 16),
        numpy_helper.from_array(rng.normal(size=12).astype(np.float32), "b1"),
        weight("w2", 16, 28),
        numpy_helper.from_array(np.array([1, 1, 2, 2], np.float32), "scales"),
        numpy_helper.from_array(np.array([1, 12, 8, 12], np.int64), "sizes"),
    ]
    graph = helper.make_graph(
        nodes,
        "unet",
        [
            helper.make_tensor_value_info("a", TensorProto.FLOAT, [1, 8, "H", "W"]),
            helper.make_tensor_value_info("b", TensorProto.FLOAT, [1, 6, "H", "W"]),
        ],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 16, "H", "W"])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)
    return onnx.shape_inference.infer_shapes(model)


def run_unet(model: onnx.ModelProto, h: int, w: int) -> np.ndarray:
    rng = np.random.default_rng(h * w)
    feed = {k: rng.normal(size=(1, c, h, w)).astype(np.float32) for k, c in (("a", 8), ("b", 6))}
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, feed)[0]


def test_padding_follows_pooling_resize_and_concat_to_the_convs_that_read_it() -> None:
    model = unet_level()
    before = [run_unet(model, h, w) for h, w in ((8, 12), (16, 20))]
    assert pad_conv_widths(model) == [("enc1", 12, 16)]
    assert pad_conv_inputs(model) == [("input_cat", 14, 16)]
    onnx.checker.check_model(model, full_check=True)
    weights = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    assert weights["w1"].shape == (16, 16, 3, 3) and not weights["w1"][12:].any()
    # the concat reads [up (12 + 4 zero channels), skip (16)]: zero columns at 12..15
    assert weights["w2"].shape == (16, 32, 3, 3) and not weights["w2"][:, 12:16].any()
    assert weights["w0"].shape == (16, 16, 3, 3) and not weights["w0"][:, 14:].any()
    assert [n.op_type for n in model.graph.node].count("ConstantOfShape") == 1
    after = [run_unet(model, h, w) for h, w in ((8, 12), (16, 20))]  # any frame size
    for a, b in zip(after, before, strict=True):
        assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max()


def test_a_resize_to_fixed_sizes_stops_the_padding() -> None:
    model = unet_level(resize_sizes=True)  # its `sizes` input fixes 12 channels
    assert pad_conv_widths(model) == []
