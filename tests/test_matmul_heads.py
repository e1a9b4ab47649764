"""Export pass `export.matmul_heads`: a 1 x 1 conv head that channel Slices split becomes one
MatMul (bias as a row of ones) per wide part and one conv per narrow part, computing the same
outputs at any batch and frame size; anything else is left alone."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.matmul_heads import BIAS_ROW_DOC, matmul_heads

SPEC = importlib.util.spec_from_file_location(
    "flops", Path(__file__).resolve().parents[1] / "benchmarks" / "flops.py"
)
flops = sys.modules["flops"] = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(flops)

C, TAPS = 8, 25  # features, kernel taps (+ 1 weight channel)


def head(
    kernel: int = 1,
    slices: tuple[tuple[int, int], ...] = ((0, TAPS), (TAPS, 2**63 - 1)),
    whole: bool = False,
    out_channels: int = TAPS + 1,
    bias: bool = True,
    batch: int | str = "N",
) -> onnx.ModelProto:
    """x (N, C, H, W) -> Conv (k x k, C -> out_channels) -> channel Slices -> Sigmoid each
    (AFN's head: logits for the filter, a fusion weight); `whole`: the conv's output read by an
    Identity too."""
    rng = np.random.default_rng(0)
    weight = rng.normal(size=(out_channels, C, kernel, kernel)).astype(np.float32)
    inits = [numpy_helper.from_array(weight, "w")]
    inputs = ["x", "w"]
    if bias:
        inits.append(numpy_helper.from_array(rng.normal(size=out_channels).astype(np.float32), "b"))
        inputs.append("b")
    p = kernel // 2
    nodes = [helper.make_node("Conv", inputs, ["y"], name="head", pads=[p] * 4)]
    outputs = []
    for k, (start, stop) in enumerate(slices):
        for name, value in ((f"s{k}", start), (f"e{k}", stop)):
            inits.append(numpy_helper.from_array(np.array([value], np.int64), name))
        nodes += [
            helper.make_node("Slice", ["y", f"s{k}", f"e{k}", "axis1"], [f"y{k}"], name=f"sl{k}"),
            helper.make_node("Sigmoid", [f"y{k}"], [f"o{k}"]),
        ]
        outputs.append(f"o{k}")
    inits.append(numpy_helper.from_array(np.array([1], np.int64), "axis1"))
    if whole:
        nodes.append(helper.make_node("Identity", ["y"], ["whole"]))
        outputs.append("whole")
    graph = helper.make_graph(
        nodes,
        "head",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [batch, C, "H", "W"])],
        [helper.make_tensor_value_info(o, TensorProto.FLOAT, None) for o in outputs],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)
    return onnx.shape_inference.infer_shapes(model)


def run(model: onnx.ModelProto, x: np.ndarray) -> list[np.ndarray]:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})


def test_split_head_becomes_matmul_and_conv_with_the_same_outputs() -> None:
    model = head()
    rng = np.random.default_rng(1)
    inputs = [rng.normal(size=s).astype(np.float32) for s in ((1, C, 12, 20), (2, C, 7, 5))]
    before = [run(model, x) for x in inputs]
    assert matmul_heads(model) == [("head", C, TAPS + 1)]
    onnx.checker.check_model(model, full_check=True)
    ops = [(n.op_type, n.doc_string == BIAS_ROW_DOC) for n in model.graph.node]
    assert ("MatMul", True) in ops and ("Conv", False) in ops  # 25 taps wide, the weight narrow
    assert not any(n.op_type == "Slice" for n in model.graph.node)
    used = {i for n in model.graph.node for i in n.input}
    assert all(i.name in used for i in model.graph.initializer)  # nothing left behind
    for x, ref in zip(inputs, before, strict=True):
        for got, want in zip(run(model, x), ref, strict=True):
            assert got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


def test_bias_row_is_the_conv_bias() -> None:
    """Without a bias the ones row gets zero weights; a negative Slice start counts from the
    end."""
    model = head(bias=False, slices=((0, TAPS), (-1, TAPS + 1)))
    x = np.random.default_rng(2).normal(size=(1, C, 6, 4)).astype(np.float32)
    before = run(model, x)
    assert matmul_heads(model)
    (weight,) = [
        numpy_helper.to_array(i)
        for i in model.graph.initializer
        if i.name.endswith("_weight") and numpy_helper.to_array(i).ndim == 2
    ]
    assert weight.shape == (TAPS, C + 1) and not weight[:, -1].any()
    for got, want in zip(run(model, x), before, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    "model",
    [
        head(kernel=3),  # a 3 x 3 conv is not a per-pixel projection
        head(whole=True),  # read whole by another op: its reorder is not avoided
        head(out_channels=C, slices=((0, C - 1), (C - 1, C))),  # no part wider than the input
        head(slices=((0, 4), (4, 8))),  # every part narrower than the input
    ],
)
def test_other_convs_are_left_alone(model: onnx.ModelProto) -> None:
    before = model.SerializeToString()
    assert matmul_heads(model) == []
    assert model.SerializeToString() == before


def test_flops_counts_the_matmul_head_as_its_conv() -> None:
    model = head(batch=1)
    before = flops.conv_costs(model, 12, 20)
    matmul_heads(model)
    after = flops.conv_costs(model, 12, 20)
    assert sum(c.macs for c in after) == sum(c.macs for c in before) == 12 * 20 * C * (TAPS + 1)
    assert sum(c.executed_macs for c in after) == 12 * 20 * (C + 1) * TAPS + 12 * 20 * C
