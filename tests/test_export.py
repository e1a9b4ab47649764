"""The exporter on a small model with state: contract names, metadata, dynamic sizes, validation."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch
from torch import nn

from rtdenoise.export.onnx_export import export_model
from rtdenoise.export.validate import synthetic_frames, torch_outputs, validate
from rtdenoise.models.base import DenoiserModel, StateSpec
from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.sequences.atomic import write_bytes_atomic as write_atomic


class EmaDenoiser(DenoiserModel):
    """Conv on color+albedo, exponential moving average kept as full- and half-resolution state."""

    family = "test-ema"
    inputs = ("color", "albedo")
    state_specs = (StateSpec("acc", 3, 1), StateSpec("low", 3, 2))
    pad_multiple = 4
    input_note = "linear radiance"

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.conv = nn.Conv2d(6, 3, 3, padding=1)
        self.pool = nn.AvgPool2d(2)

    def forward(self, buffers, state, reset):
        x = self.conv(torch.cat([buffers["color"], buffers["albedo"]], 1))
        keep = 0.8 * (1.0 - reset)
        acc = keep * state["acc"] + (1.0 - keep) * x
        low = keep * state["low"] + (1.0 - keep) * self.pool(x)
        out = acc + nn.functional.interpolate(low, scale_factor=2.0, mode="nearest")
        return out, {"acc": acc, "low": low}

    def config(self) -> dict:
        return {"width": 3}


@pytest.fixture(scope="module")
def exported() -> tuple[EmaDenoiser, onnx.ModelProto]:
    model = EmaDenoiser().eval()
    return model, export_model(model)


def test_contract_names_and_metadata(exported):
    _, proto = exported
    inputs = [i.name for i in proto.graph.input]
    outputs = [o.name for o in proto.graph.output]
    assert inputs == ["color", "albedo", "reset", "state.acc", "state.low"]
    assert outputs == ["output", "state_next.acc", "state_next.low"]
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.contract"] == "1"
    assert meta["rtdenoise.family"] == "test-ema"
    assert json.loads(meta["rtdenoise.state"]) == [
        {"name": "acc", "channels": 3, "scale": 1},
        {"name": "low", "channels": 3, "scale": 2},
    ]
    assert meta["rtdenoise.pad_multiple"] == "4"
    assert json.loads(meta["rtdenoise.inputs"])["buffers"] == ["color", "albedo"]
    assert proto.ir_version == 10
    reset = next(i for i in proto.graph.input if i.name == "reset")
    assert len(reset.type.tensor_type.shape.dim) == 0


def test_no_node_metadata_leaks_the_exporting_machine(exported):
    _, proto = exported
    assert all(not n.metadata_props for n in proto.graph.node)
    assert (
        b"/work/" not in proto.SerializeToString()
        and b"stack_trace" not in proto.SerializeToString()
    )


def test_export_then_parse_gives_back_the_declaration(exported):
    """The exporter writes with the contract module and the runtime reads with it: the parsed
    contract of the exported file is exactly what the model declared."""
    model, proto = exported
    parsed = Denoiser(proto.SerializeToString()).contract
    declared = model.declaration()
    assert parsed.declaration == declared
    assert (parsed.family, parsed.buffer_names, parsed.pad_multiple) == (
        "test-ema",
        declared.buffers,
        4,
    )
    assert [s.input_name for s in parsed.state] == ["state.acc", "state.low"]
    assert parsed.note == "linear radiance" and parsed.config == {"width": 3}
    assert declared.input_names() == [i.name for i in proto.graph.input]
    assert declared.output_names() == [o.name for o in proto.graph.output]
    assert declared.metadata() == {p.key: p.value for p in proto.metadata_props}


def test_validation_over_eight_frames_at_two_sizes(exported):
    model, proto = exported
    for h, w in [(32, 48), (20, 12)]:
        frames = synthetic_frames(model.inputs, 8, h, w)
        report = validate(model, proto.SerializeToString(), frames, tolerance=1e-4)
        assert report.passed, report.errors
        assert set(report.errors) == {"ort_fast", "ort_portable"}
        assert all(len(v) == 8 for v in report.errors.values())


def test_state_really_carries_over(exported):
    """Frame 1 of a sequence differs from frame 1 denoised alone: history is used."""
    model, proto = exported
    frames = synthetic_frames(model.inputs, 2, 16, 16)
    denoiser = Denoiser(proto.SerializeToString())
    denoiser.process(frames[0])
    with_history = denoiser.process(frames[1])
    alone = torch_outputs(model, frames[1:])[0]
    assert np.max(np.abs(with_history - alone)) > 1e-2


def test_write_atomic_leaves_nothing_on_failure(tmp_path, monkeypatch):
    target = tmp_path / "m.onnx"

    def boom(*_args, **_kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("os.replace", boom)
    with pytest.raises(OSError):
        write_atomic(target, b"data")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "family,reprojection,other",
    [
        ("wskp", "per_tap", "bilinear"),
        ("afn", "per_tap", "bilinear"),
        ("afn", "per_tap_hdr", "per_tap"),
        ("nbg", "per_tap_hdr", "per_tap"),
        ("nbg", "per_tap_hdr2", "per_tap_hdr"),
    ],
)
def test_per_tap_reprojection_exports_and_matches_ort_over_eight_frames(
    family, reprojection, other
):
    """An accumulating family with reprojection="per_tap", "per_tap_hdr" or "per_tap_hdr2"
    (small random-init weights) exports TemporalAccumulation with per_tap=1, 2 or 3 and ORT,
    fast kernels and portable bodies, follows PyTorch over the committed 64 x 64 sequence
    (fractional motion, silhouettes, a small bright light) with state fed back; the same
    weights with the `other` scheme give another image."""
    from rtdenoise.models.data import load_sequence
    from rtdenoise.models.registry import build_model, family_class
    from rtdenoise.shipped import sample_sequences

    config = {**family_class(family).example_config, "reprojection": reprojection}
    torch.manual_seed(0)
    model = build_model(family, config).eval().requires_grad_(False)
    assert model.config()["reprojection"] == reprojection
    proto = export_model(model)
    ta = [n for n in proto.graph.node if n.op_type == "TemporalAccumulation"]
    per_tap = {"per_tap": 1, "per_tap_hdr": 2, "per_tap_hdr2": 3}[reprojection]
    assert [{a.name: a.i for a in n.attribute} for n in ta] == [{"per_tap": per_tap}]
    seq = load_sequence(sample_sequences()[0], model.inputs)
    frames = [{k: v[i] for k, v in seq.buffers.items()} for i in range(seq.frames)]
    assert len(frames) == 8 and frames[0]["color"].shape[1:] == (64, 64)
    report = validate(model, proto.SerializeToString(), frames, tolerance=1e-4)
    assert report.passed, report.errors
    assert all(len(v) == 8 for v in report.errors.values())
    second = build_model(family, {**config, "reprojection": other}).eval()
    second.load_state_dict(model.state_dict())
    a, b = torch_outputs(model, frames), torch_outputs(second, frames)
    assert np.array_equal(a[0], b[0])  # frame 0: no history either way
    assert max(float(np.abs(x - y).max()) for x, y in zip(a[1:], b[1:], strict=True)) > 1e-3
