"""Export pass `export.relu_backward`: a ReLU's traced backward, Where(LessOrEqual(relu, 0), 0,
grad), becomes grad x Cast(Greater(relu, 0)) with the same values; Wheres of any other shape
stay; the shipped demo:crossreg's backward has none of the pattern left."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.learning_branch import all_nodes
from rtdenoise.export.relu_backward import relu_backward_as_mul
from rtdenoise.shipped import MODELS_DIR


def relu_backward(mask_op: str = "LessOrEqual", fill: float = 0.0, shared: bool = False):
    """y = relu(x); out = Where(mask_op(y, 0), fill, g) (and the mask as an output if shared)."""
    nodes = [
        helper.make_node("Relu", ["x"], ["y"]),
        helper.make_node(mask_op, ["y", "zero"], ["mask"], name="mask"),
        helper.make_node("Where", ["mask", "fill", "g"], ["out"], name="where"),
    ]
    value = helper.make_tensor_value_info
    outputs = [value("out", TensorProto.FLOAT, None)]
    if shared:
        outputs.append(value("mask", TensorProto.BOOL, None))
    graph = helper.make_graph(
        nodes,
        "relu_backward",
        [value("x", TensorProto.FLOAT, [1, 4, 6, 5]), value("g", TensorProto.FLOAT, [1, 4, 6, 5])],
        outputs,
        [
            numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
            numpy_helper.from_array(np.array(fill, np.float32), "fill"),
        ],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(proto: onnx.ModelProto, feed: dict) -> np.ndarray:
    so = ort.SessionOptions()
    so.log_severity_level = 3
    session = ort.InferenceSession(
        proto.SerializeToString(), so, providers=["CPUExecutionProvider"]
    )
    return session.run(None, feed)[0]


def test_the_multiply_gives_the_same_values() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(1, 4, 6, 5)).astype(np.float32)
    x[0, 0, 0, :3] = 0.0  # ReLU's boundary: masked, as Where masks it
    feed = {"x": x, "g": rng.normal(size=(1, 4, 6, 5)).astype(np.float32)}
    proto = relu_backward()
    expected = run(proto, feed)
    assert relu_backward_as_mul(proto) == ["where"]
    assert [n.op_type for n in proto.graph.node] == ["Relu", "Greater", "Cast", "Mul"]
    got = run(proto, feed)
    np.testing.assert_array_equal(got, expected)  # -0 == 0
    assert (expected[x <= 0] == 0).all() and (expected[x > 0] == feed["g"][x > 0]).all()


@pytest.mark.parametrize(
    "kwargs", [{"mask_op": "Less"}, {"fill": 1.0}, {"shared": True}], ids=["less", "fill", "shared"]
)
def test_other_wheres_stay(kwargs: dict) -> None:
    proto = relu_backward(**kwargs)
    before = proto.SerializeToString()
    assert relu_backward_as_mul(proto) == []
    assert proto.SerializeToString() == before


def test_the_shipped_crossreg_backward_has_no_relu_where() -> None:
    proto = onnx.load(MODELS_DIR / "crossreg.onnx")
    ops = [n.op_type for n in all_nodes(proto.graph)]  # the learning branch included
    assert "LessOrEqual" not in ops and ops.count("Greater") >= 9
