"""The AFN model (Lee24): shapes, state, reset, gradients, registry and config round-trip."""

from __future__ import annotations

import pytest
import torch
from model_inputs import random_buffers

from rtdenoise.models.families.afn import AFN, AFNConfig, parameter_count
from rtdenoise.models.ops import observe_calls
from rtdenoise.models.registry import build_model, default_config, families

SMALL = {"widths": [8, 12, 16], "kernel_size": 5, "refine_width": 8}
N, H, W = 2, 32, 24


def _buffers(seed: int = 0, n: int = N, h: int = H, w: int = W) -> dict[str, torch.Tensor]:
    return {k: v for k, v in random_buffers(seed, n, h, w).items() if k != "color_b"}


@pytest.fixture(scope="module")
def model() -> AFN:
    torch.manual_seed(0)
    return build_model("afn", SMALL).eval().requires_grad_(False)


def test_filter_stages_go_through_the_custom_ops(model: AFN):
    calls = {"KernelApply": [], "AdaptiveFusion": [], "Reproject": []}

    def record(op, inputs, attrs, ms):
        if op.name == "AdaptiveFusion":
            calls[op.name].append(tuple(inputs[1].shape))
        else:
            calls[op.name].append((tuple(inputs[0].shape), tuple(inputs[1].shape)))

    with observe_calls(record):
        model(_buffers(), model.initial_state(N, H, W), torch.tensor(1.0))
    # K_1spp at half resolution on the pooled 1 spp image, K_TA at full resolution (Lee24 III-B)
    assert calls["KernelApply"] == [
        ((N, 3, H // 2, W // 2), (N, 25, H // 2, W // 2)),
        ((N, 3, H, W), (N, 25, H, W)),
    ]
    assert calls["AdaptiveFusion"] == [(N, 3, H // 2, W // 2)]
    # the history (ta 4 + geometry 4 channels) is warped once by the motion vectors
    assert calls["Reproject"] == [((N, 8, H, W), (N, 2, H, W))]


def test_kernels_are_normalised_and_alpha_in_unit_range(model: AFN):
    net_in = torch.rand(1, 14, 16, 16)
    k1, kta, alpha = model.predictor(net_in)
    assert k1.shape == (1, 25, 8, 8) and kta.shape == (1, 25, 16, 16)
    torch.testing.assert_close(k1.sum(1), torch.ones(1, 8, 8))
    torch.testing.assert_close(kta.sum(1), torch.ones(1, 16, 16))
    assert float(alpha.min()) > 0.0 and float(alpha.max()) < 1.0


def test_registry_and_default_size():
    assert "afn" in families()
    cfg = default_config("afn")
    assert cfg["widths"] == [24, 32, 48] and cfg["kernel_size"] == 7
    m = build_model("afn")
    assert m.config() == cfg
    assert m.pad_multiple == 4
    assert 50_000 < parameter_count(m) < 150_000
    with pytest.raises(ValueError, match="unknown model family 'nope'"):
        build_model("nope")
    with pytest.raises(ValueError, match="unknown afn config keys"):
        build_model("afn", {"width": 3})
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        AFNConfig.from_dict({"kernel_size": 4})


def test_exports_to_onnx_with_custom_nodes_and_dynamic_size(model: AFN):
    """One graph (dynamo, dynamic H and W): the filter stages are rtdenoise custom nodes and ORT
    (fast kernels and portable function bodies) follows PyTorch over moving frames."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate
    from rtdenoise.runtime.denoiser import Denoiser

    proto = export_model(model)
    custom = [n.op_type for n in proto.graph.node if n.domain == "rtdenoise"]
    assert sorted(custom) == ["AdaptiveFusion", "KernelApply", "KernelApply", "Reproject"]
    ops_used = {n.op_type for n in proto.graph.node}
    assert {"Conv", "ReduceMax", "Exp"} <= ops_used and "GridSample" not in ops_used
    assert "Softmax" not in ops_used  # spelled out: ORT's Softmax(axis=1) is slow on CPU
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.family"] == "afn" and meta["rtdenoise.pad_multiple"] == "4"
    data = proto.SerializeToString()
    assert Denoiser(data).contract.declaration == model.declaration()  # export -> parse
    for h, w in ((32, 40), (24, 16)):
        report = validate(model, data, synthetic_frames(model.inputs, 3, h, w))
        assert report.passed and report.max_error < 1e-5, report.errors
