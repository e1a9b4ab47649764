"""export/learning_branch.py on a hand-made online graph: the update moves under an If, what
the other outputs need stays outside, and both values of the condition give what the Where
gave (the shipped demo:crossreg: tests/test_crossreg_online.py); and the backward the online
export traces (models/online.py) against autograd."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper

from rtdenoise.export.learning_branch import all_nodes, branch_learning

ONLINE = {"parameters": "theta", "moments": ["adam_m"], "step": "adam_t"}


def online_graph() -> onnx.ModelProto:
    """x, theta, m, t, freeze -> output = theta * x (the forward pass), loss; the update of
    theta, m, t gated by freeze < 0.5 as models.online.adam_step spells it."""
    f = TensorProto.FLOAT
    names = ["x", "state.theta", "state.adam_m", "state.adam_t", "state.freeze"]
    inputs = [helper.make_tensor_value_info(n, f, [4]) for n in names[:3]]
    inputs += [helper.make_tensor_value_info(n, f, [1]) for n in names[3:]]
    outs = {"output": [4], "state_next.loss": [], "state_next.theta": [4]}
    outs |= {"state_next.adam_m": [4], "state_next.adam_t": [1]}
    outputs = [helper.make_tensor_value_info(n, f, shape) for n, shape in outs.items()]
    half = helper.make_tensor("half", f, [], [0.5])
    one = helper.make_tensor("one", f, [], [1.0])
    lr = helper.make_tensor("lr", f, [], [0.1])
    nodes = [
        helper.make_node("Mul", ["state.theta", "x"], ["y"]),  # forward
        helper.make_node("Identity", ["y"], ["output"]),
        helper.make_node("ReduceSumSquare", ["y"], ["loss"], keepdims=0),
        helper.make_node("Identity", ["loss"], ["state_next.loss"]),
        helper.make_node("Mul", ["y", "x"], ["grad"]),  # backward (reads the forward's y)
        helper.make_node("Add", ["state.adam_m", "grad"], ["m1"]),
        helper.make_node("Mul", ["m1", "lr"], ["step"]),
        helper.make_node("Sub", ["state.theta", "step"], ["theta1"]),
        helper.make_node("Add", ["state.adam_t", "one"], ["t1"]),
        helper.make_node("Sub", ["one", "state.freeze"], ["learn"]),
        helper.make_node("Greater", ["learn", "half"], ["gate"]),
        helper.make_node("Where", ["gate", "theta1", "state.theta"], ["w_theta"]),
        helper.make_node("Where", ["gate", "m1", "state.adam_m"], ["w_m"]),
        helper.make_node("Where", ["gate", "t1", "state.adam_t"], ["w_t"]),
        helper.make_node("Identity", ["w_theta"], ["state_next.theta"]),
        helper.make_node("Identity", ["w_m"], ["state_next.adam_m"]),
        helper.make_node("Reshape", ["w_t", "shape1"], ["state_next.adam_t"]),
    ]
    shape1 = helper.make_tensor("shape1", TensorProto.INT64, [1], [1])
    graph = helper.make_graph(nodes, "online", inputs, outputs, [half, one, lr, shape1])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 10
    return model


def run(model: onnx.ModelProto, freeze: float) -> list[np.ndarray]:
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    feed = {n: rng.random(4, np.float32) for n in ("x", "state.theta", "state.adam_m")}
    feed |= {"state.adam_t": np.array([3.0], np.float32)}
    feed |= {"state.freeze": np.array([freeze], np.float32)}
    return session.run(None, feed)


def test_the_update_moves_under_an_if_and_gives_what_the_where_gave():
    before = online_graph()
    after = online_graph()
    assert branch_learning(after, ONLINE)
    onnx.checker.check_model(after, full_check=True)
    main = [n.op_type for n in after.graph.node]
    assert "Where" not in main and main.count("If") == 1
    (branch,) = [n for n in after.graph.node if n.op_type == "If"]
    then = next(a.g for a in branch.attribute if a.name == "then_branch")
    # the gradient, the moments and the step inside; the forward pass (read by the update
    # from the outer scope) and the condition outside
    assert sorted(n.op_type for n in then.node) == ["Add", "Add", "Mul", "Mul", "Sub"]
    outside = {o for n in after.graph.node for o in n.output}
    assert {"y", "loss", "gate"} <= outside and "grad" not in outside
    for freeze in (0.0, 1.0):
        for a, b in zip(run(before, freeze), run(after, freeze), strict=True):
            np.testing.assert_array_equal(a, b)
    assert not branch_learning(after, ONLINE)  # already branched: nothing to do
    assert not branch_learning(online_graph(), None)  # not an online model
    assert len(list(all_nodes(after.graph))) == len(before.graph.node) - 3 + 1 + 3


def test_a_learned_state_not_made_by_the_update_where_is_refused():
    model = online_graph()
    for node in model.graph.node:
        if node.output[0] == "w_m":
            node.op_type = "Max"
            node.input[:] = ["m1", "state.adam_m"]
    with pytest.raises(ValueError, match="not the update's Where"):
        branch_learning(model, ONLINE)


@pytest.mark.parametrize(
    ("c_in", "c_out", "k", "pad", "transposed"),
    [(24, 8, 3, 1, False), (8, 24, 3, 1, False), (8, 6, 1, 0, False), (16, 16, 1, 0, True)],
)
def test_the_exported_convolution_backward_is_autograds(c_in, c_out, k, pad, transposed):
    """models.online's convolution_backward decomposition (input gradient by a convolution with
    the flipped weights, weight gradient by one matrix product per tap, the smaller tensor
    shifted) gives autograd's gradients."""
    import torch
    import torch.nn.functional as F

    from rtdenoise.models.online import _convolution_backward

    gen = torch.Generator().manual_seed(0)
    x = torch.rand(1, c_in, 12, 20, generator=gen, requires_grad=True)
    shape = (c_in, c_out, 1, 1) if transposed else (c_out, c_in, k, k)
    w = torch.rand(shape, generator=gen, requires_grad=True)
    if transposed:
        y = F.conv_transpose2d(x, w, stride=2, output_padding=1)
        args = ([2, 2], [0, 0], [1, 1], True, [1, 1])
    else:
        y = F.conv2d(x, w, padding=pad)
        args = ([1, 1], [pad, pad], [1, 1], False, [0, 0])
    g = torch.rand(y.shape, generator=gen)
    ref_x, ref_w = torch.autograd.grad(y, (x, w), g)
    with torch.no_grad():
        got_x, got_w, got_b = _convolution_backward(g, x, w, None, *args, 1, [True, True, True])
    torch.testing.assert_close(got_x, ref_x, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(got_w, ref_w, rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(got_b, g.sum(dim=(0, 2, 3)))
