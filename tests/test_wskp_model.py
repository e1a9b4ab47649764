"""The WSKP model (Fan21): shapes, state, reset, the filter pipeline, gradients, export."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from model_inputs import random_buffers

from rtdenoise.export.deploy import to_deploy
from rtdenoise.models.base import parameter_count
from rtdenoise.models.families.wskp import WSKP, WSKPConfig
from rtdenoise.models.ops import observe_calls
from rtdenoise.models.registry import build_model, default_config, families
from rtdenoise.ops.weight_sharing_filter import attrs_to_sizes

N, H, W = 2, 24, 20


def _buffers(seed: int = 0, n: int = N, h: int = H, w: int = W) -> dict[str, torch.Tensor]:
    return {k: v for k, v in random_buffers(seed, n, h, w).items() if k != "color_b"}


@pytest.fixture(scope="module")
def model() -> WSKP:
    torch.manual_seed(0)
    return build_model("wskp").eval().requires_grad_(False)


def test_pipeline_with_fixed_logits_is_a_blend_of_box_means():
    """Importance logits 0 (uniform weights) and fusion logits (0, 0, -30, ...): the output is
    the average of the 3 x 3 and 5 x 5 in-bounds box means of the irradiance, remodulated."""
    m = WSKP({"bias": True, "width": 4, "layers": 2}).eval()
    s = len(m.cfg.sizes)
    with torch.no_grad():
        for p in m.parameters():
            p.zero_()
        last = m.importance_net.blocks[-1].branches[0][0]
        last.bias[s + 2 :] = -30.0  # fusion logits of sizes 7 .. 13
    b = _buffers(4)
    with torch.no_grad():
        out, _ = m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    modulation = b["albedo"] + m.cfg.albedo_eps
    r = b["color"] / modulation

    def box_mean(x: torch.Tensor, k: int) -> torch.Tensor:
        return F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False)

    expected = 0.5 * (box_mean(r, 3) + box_mean(r, 5)) * modulation
    torch.testing.assert_close(out, expected, rtol=1e-5, atol=1e-5)


def test_filter_stages_get_clamped_importance_and_the_accumulation():
    m = WSKP({"bias": True, "width": 4, "layers": 2}).eval()
    s = len(m.cfg.sizes)
    with torch.no_grad():
        bias = m.importance_net.blocks[-1].branches[0][0].bias
        bias[:s] = torch.tensor([100.0, -100.0, 0.0, 1.0, 2.0, 3.0])  # beyond the clamp
    calls = {}

    def record(op, inputs, attrs, ms):
        if op.name == "WeightSharingFilter":
            calls["wsf"] = (inputs[0].clone(), inputs[1].clone(), tuple(attrs_to_sizes(**attrs)))
        else:
            calls["kf"] = (inputs[0].shape, inputs[1].shape)

    m.importance_net.register_forward_pre_hook(lambda _, args: calls.update(net_in=args[0]))
    b = _buffers(5)
    with torch.no_grad(), observe_calls(record):
        out, _ = m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    # network input (Fan21, 10 ch): (r_TA x albedo)^(1/2.2), albedo, (n + 1) / 2, depth in [0, 1]
    net_in = calls["net_in"]
    assert net_in.shape == (N, 10, H, W)
    torch.testing.assert_close(net_in[:, :3], b["color"] ** (1 / 2.2))  # reset: r_TA = r
    torch.testing.assert_close(net_in[:, 3:6], b["albedo"])
    torch.testing.assert_close(net_in[:, 6:9], 0.5 * (b["normal"] + 1.0))
    depth = torch.log1p(b["depth"])
    torch.testing.assert_close(net_in[:, 9:], depth / depth.amax(dim=(1, 2, 3), keepdim=True))
    image, weights, sizes = calls["wsf"]
    assert sizes == (3, 5, 7, 9, 11, 13)
    torch.testing.assert_close(image, b["color"] / (b["albedo"] + m.cfg.albedo_eps))
    assert weights.shape == (N, s, H, W)
    # the importance logits (ImportanceNet output = bias here, weights being random) clamped
    assert math.isclose(float(weights[:, 0].max()), math.exp(20.0), rel_tol=1e-5)
    assert math.isclose(float(weights[:, 1].min()), math.exp(-20.0), rel_tol=1e-5)
    assert calls["kf"] == ((N, 3 * s, H, W), (N, s, H, W))
    assert torch.isfinite(out).all()


def test_gradients_reach_every_parameter_with_bn_and_bias():
    """(The plain configuration is covered by tests/test_families.py.)"""
    extra = {"bn": True, "bias": True}
    torch.manual_seed(1)
    m = build_model("wskp", {"width": 8, **extra}).train()
    state = m.initial_state(N, 16, 16)
    out, state = m(_buffers(6, h=16, w=16), state, torch.tensor(1.0))
    out2, _ = m(_buffers(7, h=16, w=16), state, torch.tensor(0.0))
    (out.mean() + out2.mean()).backward()
    missing = [n for n, p in m.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == []
    assert len(list(m.parameters())) > 0


def test_registry_config_and_size():
    assert "wskp" in families()
    cfg = default_config("wskp")
    assert cfg["width"] == 14 and cfg["layers"] == 6 and cfg["sizes"] == [3, 5, 7, 9, 11, 13]
    assert cfg["kernel_sizes"] == [5, 3, 1] and not cfg["bn"] and not cfg["bias"]
    m = build_model("wskp")
    assert m.config() == cfg and WSKP(cfg).config() == cfg
    blocks = m.importance_net.blocks
    assert [(b.in_ch, b.out_ch, b.identity is not None) for b in blocks] == [
        (10, 14, False),
        *[(14, 14, True)] * 4,
        (14, 12, False),
    ]
    # (5*5 + 3*3 + 1*1) taps per (in, out) pair, no biases: 35 * (10*14 + 4*14*14 + 14*12)
    assert parameter_count(m) == 35 * (140 + 4 * 196 + 168) == 38220
    with pytest.raises(ValueError, match="unknown wskp config keys"):
        build_model("wskp", {"widht": 3})
    with pytest.raises(ValueError, match="odd"):
        WSKPConfig.from_dict({"kernel_sizes": [5, 4]})
    with pytest.raises(ValueError, match="evenly spaced"):
        WSKPConfig.from_dict({"sizes": [3, 5, 9]})
    with pytest.raises(ValueError, match="layers"):
        WSKPConfig.from_dict({"layers": 1})


def test_three_layers_is_lee24s_timed_size():
    """Lee24 times the 3-layer WSKPN: 10 -> 14 -> 14 -> 12, one folded 5 x 5 conv per block,
    25 * (140 + 196 + 168) = 12.6 k multiply-adds per pixel (23.2 GFLOP per 720p frame)."""
    m = build_model("wskp", {"layers": 3})
    blocks = m.importance_net.blocks
    assert [(b.in_ch, b.out_ch, b.identity is not None) for b in blocks] == [
        (10, 14, False),
        (14, 14, True),
        (14, 12, False),
    ]
    deployed = to_deploy(m)
    convs = [c for c in deployed.modules() if isinstance(c, torch.nn.Conv2d)]
    assert [c.kernel_size for c in convs] == [(5, 5)] * 3
    assert sum(c.weight.numel() for c in convs) == 25 * (140 + 196 + 168) == 12_600


def test_exports_one_5x5_conv_per_block_and_matches_ort(model: WSKP):
    """Deploy form in ONNX: one 5 x 5 Conv per RepVGG block (no parallel branches), the
    filter stages as one WeightSharingFilter and one KernelFusion node; ORT (fast kernels
    and portable function bodies) follows PyTorch over a committed 8-frame sequence with
    state fed back, and over a synthetic odd-sized one."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate
    from rtdenoise.models.data import load_sequence
    from rtdenoise.runtime.denoiser import Denoiser
    from rtdenoise.shipped import sample_sequences

    proto = export_model(model)
    nodes = list(proto.graph.node)
    shapes = {t.name: tuple(t.dims) for t in proto.graph.initializer}
    convs = [n for n in nodes if n.op_type == "Conv"]
    assert len(convs) == len(model.importance_net.blocks) == 6
    assert all(shapes[c.input[1]][2:] == (5, 5) for c in convs)
    # hidden width 14 zero-padded to 16 at export (export/conv_widths.py: same function)
    assert [shapes[c.input[1]][:2] for c in convs] == [(16, 10), *[(16, 16)] * 4, (12, 16)]
    conv_outputs = {c.output[0] for c in convs}
    assert not any(
        n.op_type == "Add" and sum(i in conv_outputs for i in n.input) > 1 for n in nodes
    )
    custom = sorted(n.op_type for n in nodes if n.domain == "rtdenoise")
    assert custom == ["KernelFusion", "TemporalAccumulation", "WeightSharingFilter"]
    wsf = next(n for n in nodes if n.op_type == "WeightSharingFilter")
    assert {a.name: a.i for a in wsf.attribute} == {"size_min": 3, "size_step": 2, "count": 6}
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.family"] == "wskp" and meta["rtdenoise.pad_multiple"] == "1"

    data = proto.SerializeToString()
    assert Denoiser(data).contract.declaration == model.declaration()  # export -> parse
    seq = load_sequence(sample_sequences()[0], model.inputs)
    frames = [{k: v[i] for k, v in seq.buffers.items()} for i in range(seq.frames)]
    assert len(frames) == 8 and np.any(frames[1]["motion"] != 0)
    report = validate(model, data, frames, tolerance=1e-4)
    assert report.passed and report.max_error < 1e-5, report.errors
    assert all(len(v) == 8 for v in report.errors.values())
    report = validate(model, data, synthetic_frames(model.inputs, 3, 21, 34))
    assert report.passed, report.errors
