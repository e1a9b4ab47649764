"""benchmarks/flops.py counts the Conv multiply-adds of an exported graph: the shipped demo:afn's
count is its PyTorch modules' count (FLOP = 2 x multiply-adds)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from rtdenoise.shipped import MODELS_DIR

SPEC = importlib.util.spec_from_file_location(
    "flops", Path(__file__).resolve().parents[1] / "benchmarks" / "flops.py"
)
flops = sys.modules["flops"] = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(flops)

LEE24_BUDGET_GFLOP = 14.0  # kernel prediction in 1.46 ms on an RTX 2080 Ti (fidelity-and-specs)


def _weight(name: str, shape: tuple[int, ...]) -> onnx.TensorProto:
    return helper.make_tensor(name, TensorProto.FLOAT, shape, np.ones(shape, np.float32).ravel())


def test_counts_a_hand_made_graph_exactly():
    """3 -> 4 3x3 conv at full size, 2x2 pooling, 4 -> 8 1x1 conv in 2 groups at half size."""
    graph = helper.make_graph(
        [
            helper.make_node("Conv", ["x", "w1"], ["a"], pads=[1, 1, 1, 1]),
            helper.make_node("AveragePool", ["a"], ["b"], kernel_shape=[2, 2], strides=[2, 2]),
            helper.make_node("Conv", ["b", "w2"], ["y"], group=2),
        ],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [_weight("w1", (4, 3, 3, 3)), _weight("w2", (8, 2, 1, 1))],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    costs = flops.conv_costs(model, 40, 60)
    assert [c.output for c in costs] == [(1, 4, 40, 60), (1, 8, 20, 30)]
    assert [c.macs for c in costs] == [40 * 60 * 4 * 27, 20 * 30 * 8 * 2]
    assert flops.conv_gflop(model, 40, 60) == pytest.approx(2 * (259_200 + 9_600) / 1e9)
    assert [c.executed_macs for c in costs] == [c.macs for c in costs]


def test_zero_channels_padded_at_export_are_not_the_models_arithmetic():
    """A 3 -> 4 conv whose weights have a fourth, all-zero input channel and two all-zero output
    channels (as export/conv_widths.py pads them): 2 x 3 live of 4 x 4."""
    w = np.zeros((4, 4, 3, 3), np.float32)
    w[:2, :3] = 1.0
    graph = helper.make_graph(
        [helper.make_node("Conv", ["x", "w"], ["y"], pads=[1, 1, 1, 1])],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [helper.make_tensor("w", TensorProto.FLOAT, w.shape, w.ravel())],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    (cost,) = flops.conv_costs(model, 10, 20)
    assert cost.executed_macs == 10 * 20 * 4 * 4 * 9
    assert cost.macs == 10 * 20 * 2 * 3 * 9


def test_shipped_afn_graph_counts_what_its_modules_compute(capsys):
    """The graph count equals the torch modules' count (forward hooks), so the custom ops' shape
    rules carried the sizes to the refinement. demo:afn spends the speed headroom on capacity
    (issue 31: twice Lee24's widths, 0.83x OIDN fast's 720p time): above Lee24's 14 GFLOP for
    the kernel prediction, which the default config keeps (tests/test_afn_model.py)."""
    from model_inputs import conv_macs_per_pixel

    from rtdenoise.models.checkpoint import load_checkpoint

    model, _ = load_checkpoint(MODELS_DIR / "afn.pt")
    costs = flops.conv_costs(MODELS_DIR / "afn.onnx", 720, 1280)
    macs = sum(c.macs for c in costs)  # the NCHWc zero padding not counted
    assert macs == conv_macs_per_pixel(model) * 1280 * 720
    assert 2 * macs / 1e9 > LEE24_BUDGET_GFLOP  # the capacity the headroom bought
    flops.main(["demo:afn", "--size", "1280x720", "--json"])
    (result,) = json.loads(capsys.readouterr().out)
    assert result["gflop"] == pytest.approx(2 * macs / 1e9) and result["convs"] == len(costs)
