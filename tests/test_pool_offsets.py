"""Export pass `export.pool_offsets`: the 1 x 1 MaxPool that torch's exporter adds only to get
the plane offsets of a pool's indices becomes arithmetic on the input's shape, with the same
int64 result for any shape; a pool whose values are read, or whose indices are read otherwise,
stays."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.pool_offsets import pool_index_offsets


def exported_pattern(read_values: bool = False, whole_indices: bool = False) -> onnx.ModelProto:
    """x -> torch-style indices of a 2 x 2 max pool: ONNX indices minus the first index of each
    plane, taken from a 1 x 1 pool's indices (as torch.onnx spells max_pool2d_with_indices)."""
    nodes = [
        helper.make_node("MaxPool", ["x"], ["pooled", "idx"], name="pool", kernel_shape=[2, 2],
                         strides=[2, 2]),
        helper.make_node("MaxPool", ["x"], ["unit_values", "unit_idx"], name="unit",
                         kernel_shape=[1, 1], strides=[1, 1]),
        helper.make_node("Slice", ["unit_idx", "s", "e", "a"], ["first"], name="first"),
        helper.make_node("Sub", ["idx", "first"], ["local"], name="local"),
    ]  # fmt: skip
    outs = [helper.make_tensor_value_info("local", TensorProto.INT64, ["n", "c", "i", "j"])]
    if read_values:
        outs.append(helper.make_tensor_value_info("unit_values", TensorProto.FLOAT, None))
    if whole_indices:
        outs.append(helper.make_tensor_value_info("unit_idx", TensorProto.INT64, None))
    inits = [
        numpy_helper.from_array(np.array(v, np.int64), n)
        for n, v in (("s", [0, 0]), ("e", [1, 1]), ("a", [2, 3]))
    ]
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", "c", "h", "w"])
    graph = helper.make_graph(nodes, "pool", [x], outs, inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})[0]


def test_the_unit_pool_becomes_shape_arithmetic_with_the_same_indices() -> None:
    model = exported_pattern()
    rng = np.random.default_rng(0)
    shapes = [(1, 3, 8, 10), (2, 5, 6, 4), (3, 1, 12, 2)]
    before = [run(model, rng.random(s, dtype=np.float32)) for s in shapes]
    rng = np.random.default_rng(0)
    assert pool_index_offsets(model) == ["unit"]
    onnx.checker.check_model(model, full_check=True)
    pools = [n.name for n in model.graph.node if n.op_type == "MaxPool"]
    assert pools == ["pool"]  # the 2 x 2 one stays
    for shape, want in zip(shapes, before, strict=True):
        got = run(model, rng.random(shape, dtype=np.float32))
        np.testing.assert_array_equal(got, want)
        assert got.min() >= 0 and got.max() < shape[2] * shape[3]  # torch's per-plane index


def test_a_unit_pool_read_otherwise_stays() -> None:
    for kwargs in ({"read_values": True}, {"whole_indices": True}):
        model = exported_pattern(**kwargs)
        assert pool_index_offsets(model) == []
        assert sum(n.op_type == "MaxPool" for n in model.graph.node) == 2
