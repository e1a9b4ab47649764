"""Small ONNX models that obey (or deliberately break) the rtdenoise contract v1.

Built with onnx.helper from standard ops only, IR 10 / opset 18 (what ONNX Runtime 1.31
accepts). Each model has a numpy reference in the tests.

- `ema_model`: buffers color, albedo; state `acc` (3 ch, full res); pad_multiple 4.
    cur = 0.75 * box3x3(color, zero pad) + 0.25 * up4(avgpool4(color))
    acc_next = 0.5 * cur + 0.5 * (acc * (1 - reset) + cur * reset)
    output = acc_next * albedo
  The 4x4 pool makes the graph fail unless H, W are multiples of 4.
- `samples_model`: stateless, no reset; output = mean over S of rank-5 `samples`.
- `probe_model`: output = state_next.acc = state.acc + color + 100 * reset (shows the feeds).
- `blowup_model`: output = state_next.acc = 1e30 * state.acc + color: overflows to Inf on the
  third frame from finite input (a model bug, for the output and state guards).
- `halfres_model`: buffers color, depth; state `low` (4 ch, scale 2); pad_multiple 2.
    low_in = avgpool2(concat(color, depth))
    low_next = 0.8 * (low * (1 - reset) + low_in * reset) + 0.2 * low_in
    output = 0.5 * color + 0.5 * up2(low_next[:3])
"""

from __future__ import annotations

import json

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

IR_VERSION = 10
OPSET = 18
F = TensorProto.FLOAT


def contract_metadata(
    family: str, buffers: list[str], state: list[dict], pad_multiple: int, config: dict
) -> dict[str, str]:
    """The metadata_props of a contract-v1 model."""
    return {
        "rtdenoise.contract": "1",
        "rtdenoise.family": family,
        "rtdenoise.config": json.dumps(config),
        "rtdenoise.inputs": json.dumps({"buffers": buffers, "note": "linear radiance"}),
        "rtdenoise.state": json.dumps(state),
        "rtdenoise.pad_multiple": str(pad_multiple),
    }


def make_model(
    nodes: list[onnx.NodeProto],
    inputs: list[onnx.ValueInfoProto],
    outputs: list[onnx.ValueInfoProto],
    initializers: list[onnx.TensorProto],
    metadata: dict[str, str | None],
    *,
    check: bool = True,
) -> bytes:
    """Serialized model; metadata entries whose value is None are left out."""
    graph = helper.make_graph(nodes, "contract_test", inputs, outputs, initializers)
    model = helper.make_model(
        graph, ir_version=IR_VERSION, opset_imports=[helper.make_opsetid("", OPSET)]
    )
    for key, value in metadata.items():
        if value is not None:
            model.metadata_props.add(key=key, value=value)
    if check:
        onnx.checker.check_model(model, full_check=True)
    return model.SerializeToString()


def _const(name: str, value) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(value, np.float32), name)


def _nchw(name: str, channels: int | str, h: str = "H", w: str = "W") -> onnx.ValueInfoProto:
    return helper.make_tensor_value_info(name, F, [1, channels, h, w])


def ema_model(
    *,
    metadata: dict[str, str | None] | None = None,
    drop_state_next: bool = False,
    reset_shape: list | None = None,
    extra_input: str | None = None,
) -> bytes:
    """The EMA denoiser above; the keyword arguments break the contract for tests."""
    nodes = [
        helper.make_node("Conv", ["color", "box_w"], ["blur"], group=3, pads=[1, 1, 1, 1]),
        helper.make_node("AveragePool", ["color"], ["pool4"], kernel_shape=[4, 4], strides=[4, 4]),
        helper.make_node("Resize", ["pool4", "", "up4"], ["coarse"], mode="nearest"),
        helper.make_node("Mul", ["blur", "c075"], ["blur_w"]),
        helper.make_node("Mul", ["coarse", "c025"], ["coarse_w"]),
        helper.make_node("Add", ["blur_w", "coarse_w"], ["cur"]),
        helper.make_node("Sub", ["one", "reset"], ["keep"]),
        helper.make_node("Mul", ["state.acc", "keep"], ["hist_a"]),
        helper.make_node("Mul", ["cur", "reset"], ["hist_b"]),
        helper.make_node("Add", ["hist_a", "hist_b"], ["hist"]),
        helper.make_node("Add", ["cur", "hist"], ["sum"]),
        helper.make_node("Mul", ["sum", "c05"], ["state_next.acc"]),
        helper.make_node("Mul", ["state_next.acc", "albedo"], ["output"]),
    ]
    inputs = [
        _nchw("color", 3),
        _nchw("albedo", 3),
        helper.make_tensor_value_info("reset", F, [] if reset_shape is None else reset_shape),
        _nchw("state.acc", 3),
    ]
    if extra_input:
        inputs.append(_nchw(extra_input, 3))
        nodes.append(helper.make_node("Identity", [extra_input], ["unused_extra"]))
    outputs = [_nchw("output", 3)]
    if not drop_state_next:
        outputs.append(_nchw("state_next.acc", 3))
    inits = [
        _const("box_w", np.full((3, 1, 3, 3), 1.0 / 9.0)),
        _const("up4", [1, 1, 4, 4]),
        _const("c075", 0.75),
        _const("c025", 0.25),
        _const("c05", 0.5),
        _const("one", 1.0),
    ]
    meta = contract_metadata(
        "ema", ["color", "albedo"], [{"name": "acc", "channels": 3, "scale": 1}], 4, {"k": 0.5}
    )
    meta.update(metadata or {})
    return make_model(nodes, inputs, outputs, inits, meta, check=not extra_input)


def halfres_model() -> bytes:
    """The half-resolution-state model above."""
    nodes = [
        helper.make_node("Concat", ["color", "depth"], ["cd"], axis=1),
        helper.make_node("AveragePool", ["cd"], ["low_in"], kernel_shape=[2, 2], strides=[2, 2]),
        helper.make_node("Sub", ["one", "reset"], ["keep"]),
        helper.make_node("Mul", ["state.low", "keep"], ["hist_a"]),
        helper.make_node("Mul", ["low_in", "reset"], ["hist_b"]),
        helper.make_node("Add", ["hist_a", "hist_b"], ["hist"]),
        helper.make_node("Mul", ["hist", "c08"], ["hist_w"]),
        helper.make_node("Mul", ["low_in", "c02"], ["in_w"]),
        helper.make_node("Add", ["hist_w", "in_w"], ["state_next.low"]),
        helper.make_node("Slice", ["state_next.low", "s0", "s3", "s_axis"], ["low_rgb"]),
        helper.make_node("Resize", ["low_rgb", "", "up2"], ["up"], mode="nearest"),
        helper.make_node("Add", ["color", "up"], ["sum"]),
        helper.make_node("Mul", ["sum", "c05"], ["output"]),
    ]
    inputs = [
        _nchw("color", 3),
        _nchw("depth", 1),
        helper.make_tensor_value_info("reset", F, []),
        _nchw("state.low", 4, "H2", "W2"),
    ]
    outputs = [_nchw("output", 3), _nchw("state_next.low", 4, "H2", "W2")]
    inits = [
        _const("up2", [1, 1, 2, 2]),
        _const("c08", 0.8),
        _const("c02", 0.2),
        _const("c05", 0.5),
        _const("one", 1.0),
        numpy_helper.from_array(np.array([0], np.int64), "s0"),
        numpy_helper.from_array(np.array([3], np.int64), "s3"),
        numpy_helper.from_array(np.array([1], np.int64), "s_axis"),
    ]
    meta = contract_metadata(
        "halfres", ["color", "depth"], [{"name": "low", "channels": 4, "scale": 2}], 2, {}
    )
    return make_model(nodes, inputs, outputs, inits, meta)


def probe_model(pad_multiple: int = 1) -> bytes:
    """Shows what the executor feeds: state_next.acc = state.acc + color + 100 * reset = output."""
    nodes = [
        helper.make_node("Mul", ["reset", "c100"], ["r100"]),
        helper.make_node("Add", ["state.acc", "color"], ["s"]),
        helper.make_node("Add", ["s", "r100"], ["state_next.acc"]),
        helper.make_node("Identity", ["state_next.acc"], ["output"]),
    ]
    inputs = [
        _nchw("color", 3),
        helper.make_tensor_value_info("reset", F, []),
        _nchw("state.acc", 3),
    ]
    outputs = [_nchw("output", 3), _nchw("state_next.acc", 3)]
    meta = contract_metadata("probe", ["color"], [{"name": "acc", "channels": 3}], pad_multiple, {})
    return make_model(nodes, inputs, outputs, [_const("c100", 100.0)], meta)


def blowup_model() -> bytes:
    """output = state_next.acc = 1e30 * state.acc + color (see the module docstring)."""
    nodes = [
        helper.make_node("Mul", ["state.acc", "c1e30"], ["big"]),
        helper.make_node("Add", ["big", "color"], ["state_next.acc"]),
        helper.make_node("Identity", ["state_next.acc"], ["output"]),
    ]
    inputs = [
        _nchw("color", 3),
        helper.make_tensor_value_info("reset", F, []),
        _nchw("state.acc", 3),
    ]
    outputs = [_nchw("output", 3), _nchw("state_next.acc", 3)]
    meta = contract_metadata("blowup", ["color"], [{"name": "acc", "channels": 3}], 1, {})
    return make_model(nodes, inputs, outputs, [_const("c1e30", 1e30)], meta)


def samples_model() -> bytes:
    """Stateless, no `reset` input: output = mean over S of `samples` [1, S, 3, H, W]; pad 4."""
    nodes = [helper.make_node("ReduceMean", ["samples", "axis1"], ["output"], keepdims=0)]
    inputs = [helper.make_tensor_value_info("samples", F, [1, "S", 3, "H", "W"])]
    inits = [numpy_helper.from_array(np.array([1], np.int64), "axis1")]
    meta = contract_metadata("samples", ["samples"], [], 4, {})
    return make_model(nodes, inputs, [_nchw("output", 3)], inits, meta)


# -- numpy references ---------------------------------------------------------------------


def _pad_edge(x: np.ndarray, m: int, margin: int = 0) -> np.ndarray:
    """`margin` edge pixels on every side, then the bottom and right up to multiples of m."""
    h, w = (n + 2 * margin for n in x.shape[-2:])
    widths = ((0, 0), (margin, margin + -h % m), (margin, margin + -w % m))
    return np.pad(x, widths, mode="edge")


def _box3(x: np.ndarray) -> np.ndarray:
    c, h, w = x.shape
    p = np.pad(x.astype(np.float64), ((0, 0), (1, 1), (1, 1)))
    return sum(p[:, i : i + h, j : j + w] for i in range(3) for j in range(3)) / 9.0


def _pool(x: np.ndarray, k: int) -> np.ndarray:
    c, h, w = x.shape
    return x.astype(np.float64).reshape(c, h // k, k, w // k, k).mean(axis=(2, 4))


def _up(x: np.ndarray, k: int) -> np.ndarray:
    return x.repeat(k, axis=1).repeat(k, axis=2)


class EmaReference:
    """numpy EMA model over padded frames (`margin`: edge pixels repeated on every side first,
    as `rtdenoise.edge_margin` asks); `step` returns the cropped (3, H, W) output."""

    pad = 4

    def __init__(self, margin: int = 0) -> None:
        self.acc: np.ndarray | None = None
        self.margin = margin

    def step(self, color: np.ndarray, albedo: np.ndarray, reset: bool) -> np.ndarray:
        (h, w), m = color.shape[-2:], self.margin
        color, albedo = _pad_edge(color, self.pad, m), _pad_edge(albedo, self.pad, m)
        cur = 0.75 * _box3(color) + 0.25 * _up(_pool(color, 4), 4)
        hist = cur if reset or self.acc is None else self.acc
        self.acc = 0.5 * cur + 0.5 * hist
        return (self.acc * albedo)[:, m : m + h, m : m + w]


class HalfresReference:
    """numpy reference of `halfres_model`; `low` is the (4, H/2, W/2) state."""

    pad = 2

    def __init__(self) -> None:
        self.low: np.ndarray | None = None

    def step(self, color: np.ndarray, depth: np.ndarray, reset: bool) -> np.ndarray:
        h, w = color.shape[-2:]
        color, depth = _pad_edge(color, self.pad), _pad_edge(depth, self.pad)
        low_in = _pool(np.concatenate([color, depth]), 2)
        hist = low_in if reset or self.low is None else self.low
        self.low = 0.8 * hist + 0.2 * low_in
        return (0.5 * color + 0.5 * _up(self.low[:3], 2))[:, :h, :w]
