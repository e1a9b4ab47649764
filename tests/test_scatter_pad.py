"""Export pass `export.scatter_pad`: torch.onnx's spelling of a slice_scatter into zeros
(Transpose, ScatterND with a Range slice, Transpose back) becomes a Pad with the same values,
for a slice to the end and a bounded one; patterns it cannot prove stay; the shipped
demo:crossreg (whose backward had six) holds none."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.learning_branch import all_nodes
from rtdenoise.export.scatter_pad import slice_scatter_as_pad
from rtdenoise.shipped import MODELS_DIR

BIG = 9223372036854775807  # torch.onnx's "to the end"


def exported_pattern(channels: int, start: int, end: int, reduction: str = "none",
                     constant_size: bool = True) -> onnx.ModelProto:  # fmt: skip
    """slice_scatter(zeros(1, channels, H, W), x, dim=1, start, end) as torch.onnx writes it."""
    consts = {
        "one": [1], "channels": [channels], "zero_s": 0, "one_s": 1, "axis": 1,
        "start": [start], "end": [end], "axes0": [0], "step": [1], "last": [-1],
    }  # fmt: skip
    inits = [numpy_helper.from_array(np.array(v, np.int64), k) for k, v in consts.items()]
    size_part = "channels" if constant_size else "dyn_c"
    nodes = [
        helper.make_node("Shape", ["x"], ["hw"], start=2),
        helper.make_node("Shape", ["y"], ["dyn_c"], start=1, end=2),
        helper.make_node("Concat", ["one", size_part, "hw"], ["zshape"], axis=0),
        helper.make_node("ConstantOfShape", ["zshape"], ["zeros"], name="zeros",
                         value=helper.make_tensor("value", TensorProto.FLOAT, [1], [0.0])),
        helper.make_node("Shape", ["zeros"], ["zs"], name="zs"),
        helper.make_node("Gather", ["zs", "axis"], ["n"], name="n", axis=0),
        helper.make_node("Range", ["zero_s", "n", "one_s"], ["all"], name="all"),
        helper.make_node("Slice", ["all", "start", "end", "axes0", "step"], ["idx"], name="idx"),
        helper.make_node("Unsqueeze", ["idx", "last"], ["idx2"], name="idx2"),
        helper.make_node("Transpose", ["zeros"], ["zt"], name="zt", perm=[1, 0, 2, 3]),
        helper.make_node("Transpose", ["x"], ["xt"], name="xt", perm=[1, 0, 2, 3]),
        helper.make_node("ScatterND", ["zt", "idx2", "xt"], ["st"], name="scatter",
                         reduction=reduction),
        helper.make_node("Transpose", ["st"], ["out"], name="back", perm=[1, 0, 2, 3]),
    ]  # fmt: skip
    graph = helper.make_graph(
        nodes,
        "slice_scatter",
        [
            helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, None, "h", "w"]),
            helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, channels]),
        ],  # fmt: skip
        [helper.make_tensor_value_info("out", TensorProto.FLOAT, None)],
        inits,
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(proto: onnx.ModelProto, x: np.ndarray, channels: int) -> np.ndarray:
    so = ort.SessionOptions()
    so.log_severity_level = 3
    session = ort.InferenceSession(
        proto.SerializeToString(), so, providers=["CPUExecutionProvider"]
    )
    return session.run(None, {"x": x, "y": np.zeros((1, channels), np.float32)})[0]


@pytest.mark.parametrize("channels, start, end", [(4, 3, BIG), (4, 0, 3), (6, 5, 6), (6, 1, 4)])
def test_the_pad_gives_the_same_tensor(channels: int, start: int, end: int) -> None:
    x = np.random.default_rng(0).normal(size=(1, min(end, channels) - start, 5, 7))
    x = x.astype(np.float32)
    proto = exported_pattern(channels, start, end)
    expected = run(proto, x, channels)
    assert slice_scatter_as_pad(proto) == ["scatter"]
    ops = [n.op_type for n in proto.graph.node]
    assert "ScatterND" not in ops and "Transpose" not in ops and "Range" not in ops
    assert ops.count("Pad") == 1
    got = run(proto, x, channels)
    np.testing.assert_array_equal(got, expected)
    assert got.shape == (1, channels, 5, 7)


@pytest.mark.parametrize("kwargs", [{"reduction": "add"}, {"constant_size": False}])
def test_patterns_it_cannot_prove_stay(kwargs: dict) -> None:
    proto = exported_pattern(4, 3, BIG, **kwargs)
    before = proto.SerializeToString()
    assert slice_scatter_as_pad(proto) == []
    assert proto.SerializeToString() == before


def test_the_shipped_crossreg_backward_has_no_scatter() -> None:
    proto = onnx.load(MODELS_DIR / "crossreg.onnx")
    ops = [n.op_type for n in all_nodes(proto.graph)]  # the learning branch included
    assert "ScatterND" not in ops and ops.count("Pad") >= 6
