"""The AFN model (Lee24): shapes, state, reset, gradients, registry and config round-trip."""

from __future__ import annotations

import pytest
import torch

from rtdenoise.models import afn as afn_module
from rtdenoise.models.afn import AFN, AFNConfig, parameter_count
from rtdenoise.models.checkpoint import load_checkpoint, save_checkpoint
from rtdenoise.models.registry import build_model, default_config, families

SMALL = {"widths": [8, 12, 16], "kernel_size": 5, "refine_width": 8}
N, H, W = 2, 32, 24


def _buffers(seed: int = 0, n: int = N, h: int = H, w: int = W) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return {
        "color": torch.rand(n, 3, h, w, generator=g) * 4.0,
        "albedo": torch.rand(n, 3, h, w, generator=g),
        "normal": torch.nn.functional.normalize(torch.randn(n, 3, h, w, generator=g), dim=1),
        "depth": 1.0 + torch.rand(n, 1, h, w, generator=g) * 5.0,
        "motion": (torch.rand(n, 2, h, w, generator=g) - 0.5) * 3.0,
    }


@pytest.fixture(scope="module")
def model() -> AFN:
    torch.manual_seed(0)
    return build_model("afn", SMALL).eval().requires_grad_(False)


def test_forward_shapes_state_and_range(model: AFN):
    assert model.pad_multiple == 4
    state = model.initial_state(N, H, W)
    out, nxt = model(_buffers(), state, torch.tensor(1.0))
    assert out.shape == (N, 3, H, W)
    assert set(nxt) == {s.name for s in model.state_specs} == {"ta", "geometry"}
    for spec in model.state_specs:
        assert nxt[spec.name].shape == (N, spec.channels, H // spec.scale, W // spec.scale)
    assert torch.isfinite(out).all() and float(out.min()) >= 0.0
    # extreme but legal inputs: fireflies, zero albedo, background depth, zero normals
    b = _buffers(1)
    b["color"][:, :, :4] = 1e4
    b["albedo"][:, :, 4:8] = 0.0
    b["depth"][:, :, 8:12] = 1e4
    b["normal"][:, :, 12:16] = 0.0
    out2, nxt2 = model(b, nxt, torch.tensor(0.0))
    assert torch.isfinite(out2).all() and float(out2.min()) >= 0.0
    assert all(torch.isfinite(v).all() for v in nxt2.values())


def test_next_state_holds_accumulation_and_geometry(model: AFN):
    b = _buffers(2)
    _, nxt = model(b, model.initial_state(N, H, W), torch.tensor(1.0))
    irradiance = b["color"] / (b["albedo"] + model.cfg.albedo_eps)
    torch.testing.assert_close(nxt["ta"][:, :3], irradiance)  # reset: TA = current frame
    torch.testing.assert_close(nxt["ta"][:, 3:], torch.ones(N, 1, H, W))  # history length 1
    torch.testing.assert_close(nxt["geometry"], torch.cat((b["normal"], b["depth"]), dim=1))


def test_reset_ignores_state_values(model: AFN):
    b = _buffers(3)
    g = torch.Generator().manual_seed(9)
    s1 = {k: torch.rand(v.shape, generator=g) * 10 for k, v in model.initial_state(N, H, W).items()}
    s2 = {k: torch.rand(v.shape, generator=g) for k, v in model.initial_state(N, H, W).items()}
    o1, n1 = model(b, s1, torch.tensor(1.0))
    o2, n2 = model(b, s2, torch.tensor(1.0))
    torch.testing.assert_close(o1, o2, atol=0, rtol=0)
    for k in n1:
        torch.testing.assert_close(n1[k], n2[k], atol=0, rtol=0)
    # without reset, a valid history changes the result (the state is really used)
    static = dict(b, motion=torch.zeros(N, 2, H, W))
    _, warm = model(static, s1, torch.tensor(1.0))
    warm = {"ta": warm["ta"] * 3.0 + 1.0, "geometry": warm["geometry"]}
    o3, _ = model(static, warm, torch.tensor(0.0))
    o4, _ = model(static, warm, torch.tensor(1.0))
    assert float((o3 - o4).abs().max()) > 1e-3


def test_gradients_reach_every_parameter():
    torch.manual_seed(1)
    m = build_model("afn", SMALL).train()
    state = m.initial_state(N, H, W)
    out, state = m(_buffers(4), state, torch.tensor(1.0))
    out2, _ = m(_buffers(5), state, torch.tensor(0.0))
    (out.mean() + out2.mean()).backward()
    missing = [n for n, p in m.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == []


def test_filter_stages_go_through_the_custom_ops(monkeypatch, model: AFN):
    calls = {"kernel_apply": [], "adaptive_fusion": []}
    ka, af = afn_module.ops.kernel_apply, afn_module.ops.adaptive_fusion

    def kernel_apply(image, kernel, dilation=1):
        calls["kernel_apply"].append((tuple(image.shape), tuple(kernel.shape)))
        return ka(image, kernel, dilation)

    def adaptive_fusion(d_ta, d_low, alpha):
        calls["adaptive_fusion"].append(tuple(d_low.shape))
        return af(d_ta, d_low, alpha)

    monkeypatch.setattr(afn_module.ops, "kernel_apply", kernel_apply)
    monkeypatch.setattr(afn_module.ops, "adaptive_fusion", adaptive_fusion)
    model(_buffers(), model.initial_state(N, H, W), torch.tensor(1.0))
    # K_1spp at half resolution on the pooled 1 spp image, K_TA at full resolution (Lee24 III-B)
    assert calls["kernel_apply"] == [
        ((N, 3, H // 2, W // 2), (N, 25, H // 2, W // 2)),
        ((N, 3, H, W), (N, 25, H, W)),
    ]
    assert calls["adaptive_fusion"] == [(N, 3, H // 2, W // 2)]


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


def test_config_roundtrip_through_checkpoint(tmp_path, model: AFN):
    path = save_checkpoint(tmp_path / "afn.pt", model, {"note": "test"})
    loaded, meta = load_checkpoint(path)
    assert isinstance(loaded, AFN) and meta == {"note": "test"}
    assert loaded.config() == model.config() == AFN(model.config()).config()
    b = _buffers(6)
    state = model.initial_state(N, H, W)
    with torch.no_grad():
        ref, ref_state = model(b, state, torch.tensor(1.0))
        out, out_state = loaded(b, state, torch.tensor(1.0))
    torch.testing.assert_close(out, ref, atol=0, rtol=0)
    torch.testing.assert_close(out_state["ta"], ref_state["ta"], atol=0, rtol=0)


def test_exports_to_onnx_with_custom_nodes_and_dynamic_size(model: AFN):
    """One graph (dynamo, dynamic H and W): the filter stages are rtdenoise custom nodes and ORT
    (fast kernels and portable function bodies) follows PyTorch over moving frames."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate

    proto = export_model(model)
    custom = [n.op_type for n in proto.graph.node if n.domain == "rtdenoise"]
    assert sorted(custom) == ["AdaptiveFusion", "KernelApply", "KernelApply"]
    ops_used = {n.op_type for n in proto.graph.node}
    assert {"GridSample", "Conv", "ReduceMax", "Exp"} <= ops_used
    assert "Softmax" not in ops_used  # spelled out: ORT's Softmax(axis=1) is slow on CPU
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.family"] == "afn" and meta["rtdenoise.pad_multiple"] == "4"
    data = proto.SerializeToString()
    for h, w in ((32, 40), (24, 16)):
        report = validate(model, data, synthetic_frames(model.inputs, 3, h, w))
        assert report.passed and report.max_error < 1e-5, report.errors
