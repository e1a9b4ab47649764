"""Export pass `export.conv_widths.pad_conv_widths`: hidden conv widths zero-padded to a multiple
of 8 (ORT's NCHWc layout) compute the same function, and only provably safe chains change."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.conv_widths import pad_conv_widths


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
