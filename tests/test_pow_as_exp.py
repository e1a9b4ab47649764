"""Export pass `export.pow_as_exp`: x ** c with a constant fractional c becomes exp(c log x),
equal to ORT's Pow within float32 rounding for every input but -inf (NaN there), NaN and inf
where Pow gives them; x ** 1 becomes Identity, bit for bit; other integer exponents keep their
Pow."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.pow_as_exp import pow_as_exp


def powers(*exponents: float, dtype=np.float32) -> onnx.ModelProto:
    """x -> Pow(x, c) for each c (outputs y0, y1, ...)."""
    nodes, inits, outs = [], [], []
    for k, c in enumerate(exponents):
        inits.append(numpy_helper.from_array(np.array(c, dtype), f"c{k}"))
        nodes.append(helper.make_node("Pow", ["x", f"c{k}"], [f"y{k}"], name=f"pow{k}"))
        outs.append(helper.make_tensor_value_info(f"y{k}", TensorProto.FLOAT, ["n"]))
    graph = helper.make_graph(
        nodes, "powers", [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n"])], outs,
        inits,
    )  # fmt: skip
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10)


def run(model: onnx.ModelProto, x: np.ndarray) -> list[np.ndarray]:
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"x": x})


def test_fractional_exponents_become_exp_log_with_the_same_values() -> None:
    model = powers(1 / 2.2, 2.2, -0.5, dtype=np.float32)
    special = [0.0, -0.0, -1.0, -3.5, 1.0, np.inf, -np.inf, np.nan, 1e-30, 1e4]
    x = np.concatenate([special, np.random.default_rng(0).random(1000) * 50]).astype(np.float32)
    before = run(model, x)
    assert pow_as_exp(model) == ["pow0", "pow1", "pow2"]
    onnx.checker.check_model(model, full_check=True)
    assert not any(n.op_type == "Pow" for n in model.graph.node)
    for got, want in zip(run(model, x), before, strict=True):
        assert np.isnan(got[x == -np.inf]).all()  # C's pow: inf or 0
        got, want = got[x != -np.inf], want[x != -np.inf]
        assert np.array_equal(np.isnan(got), np.isnan(want))
        assert np.array_equal(np.isinf(got), np.isinf(want))
        finite = np.isfinite(want)
        np.testing.assert_allclose(got[finite], want[finite], rtol=2e-6, atol=0)


def test_double_exponent_is_applied_in_float32() -> None:
    model = powers(1 / 2.2, dtype=np.float64)  # Pow allows another type for the exponent
    x = np.linspace(0, 8, 33, dtype=np.float32)
    before = run(model, x)[0]
    assert pow_as_exp(model) == ["pow0"]
    onnx.checker.check_model(model, full_check=True)
    np.testing.assert_allclose(run(model, x)[0], before, rtol=2e-6)


def test_integer_exponents_keep_their_pow() -> None:
    model = powers(2.0, -1.0, 3.0)  # (-2) ** 2 = 4, but log(-2) is NaN
    before = model.SerializeToString()
    assert pow_as_exp(model) == []
    assert model.SerializeToString() == before


def test_exponent_one_becomes_identity_bit_for_bit() -> None:
    model = powers(1.0, 2.0, 1.0, dtype=np.float32)
    special = [0.0, -0.0, -1.0, -3.5, 1.0, np.inf, -np.inf, np.nan, 1e-30, -1e-40, 1e4]
    x = np.concatenate([special, np.random.default_rng(0).standard_normal(1000) * 50])
    x = x.astype(np.float32)
    before = run(model, x)
    assert pow_as_exp(model) == ["pow0", "pow2"]
    onnx.checker.check_model(model, full_check=True)
    assert [n.op_type for n in model.graph.node] == ["Identity", "Pow", "Identity"]
    assert sorted(i.name for i in model.graph.initializer) == ["c1"]  # c0, c2 unread: dropped
    for got, want in zip(run(model, x), before, strict=True):
        assert got.tobytes() == want.tobytes()
