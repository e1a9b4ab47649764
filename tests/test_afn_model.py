"""The AFN model (Lee24): shapes, state, reset, gradients, registry and config round-trip."""

from __future__ import annotations

import pytest
import torch
from model_inputs import conv_macs_per_pixel, random_buffers

from rtdenoise.models.families.afn import AFN, LEGACY_CONFIG, AFNConfig, parameter_count
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
    calls = {"SoftmaxKernelApply": [], "AdaptiveFusion": [], "TemporalAccumulation": []}

    def record(op, inputs, attrs, ms):
        if op.name == "AdaptiveFusion":
            calls[op.name].append(tuple(inputs[1].shape))
        else:
            calls[op.name].append((tuple(inputs[0].shape), tuple(inputs[1].shape)))

    with observe_calls(record):
        model(_buffers(), model.initial_state(N, H, W), torch.tensor(1.0))
    # K_1spp at half resolution on the pooled 1 spp image, K_TA at full resolution (Lee24 III-B)
    assert calls["SoftmaxKernelApply"] == [
        ((N, 3, H // 2, W // 2), (N, 25, H // 2, W // 2)),
        ((N, 3, H, W), (N, 25, H, W)),
    ]
    assert calls["AdaptiveFusion"] == [(N, 3, H // 2, W // 2)]
    # one temporal accumulation step of the demodulated 3-channel frame, with the motion
    assert calls["TemporalAccumulation"] == [((N, 3, H, W), (N, 2, H, W))]


def test_kernel_logits_and_alpha_in_unit_range(model: AFN):
    net_in = torch.rand(1, 14, 16, 16)
    k1, kta, alpha = model.predictor(net_in)
    assert k1.shape == (1, 25, 8, 8) and kta.shape == (1, 25, 16, 16)
    assert alpha.shape == (1, 1, 16, 16)
    assert float(alpha.min()) > 0.0 and float(alpha.max()) < 1.0


def test_registry_and_default_size():
    assert "afn" in families()
    cfg = default_config("afn")
    assert cfg["widths"] == [16, 12, 16, 24, 32] and cfg["kernel_size"] == 7
    assert cfg["full_res_convs"] == 1 and cfg["full_res_decoder_kernel"] == 1
    assert cfg["refine_width"] == 4 and cfg["refine_layers"] == 2
    m = build_model("afn")
    assert m.config() == cfg
    assert m.pad_multiple == 16
    assert parameter_count(m) == 66_218
    with pytest.raises(ValueError, match="unknown model family 'nope'"):
        build_model("nope")
    with pytest.raises(ValueError, match="unknown afn config keys"):
        build_model("afn", {"width": 3})
    with pytest.raises(ValueError, match="kernel_size must be odd"):
        AFNConfig.from_dict({"kernel_size": 4})


def test_default_is_within_lee24_budget_and_legacy_is_not():
    """Lee24 times kernel prediction at 1.46 ms per 720p frame (about 8 k multiply-adds per
    pixel, 14 GFLOP): the default network, predictor and refinement together, fits; the model
    the demo shipped before (45.5 k, 83.9 GFLOP) does not. By hand, per scale 1/2**l (l > 0):
    9 * (c_in * w + w * w) / 4**l per encoder block, 9 * ((w_below + w) * w + w * w) / 4**l per
    decoder block; full scale one 3 x 3 conv 14 -> 16 and one 1 x 1 conv 12 + 16 -> 16; heads
    16 * 50 + 12 * 49 / 4; refinement 9 * (10 * 4 + 4 * 3)."""
    widths, c_in, macs = (16, 12, 16, 24, 32), 16, 9 * 14 * 16 + (12 + 16) * 16
    for level, w in enumerate(widths[1:], start=1):
        macs += 9 * (c_in * w + w * w) / 4**level
        c_in = w
    for level, w in enumerate(widths[1:-1], start=1):
        macs += 9 * ((widths[level + 1] + w) * w + w * w) / 4**level
    macs += 16 * 50 + 12 * 49 / 4 + 9 * (10 * 4 + 4 * 3)
    with torch.no_grad():
        light = conv_macs_per_pixel(build_model("afn").eval())
        legacy = conv_macs_per_pixel(build_model("afn", LEGACY_CONFIG).eval())
    assert light == macs == 6939.0 and legacy == 45512.0
    assert 2 * light * 1280 * 720 / 1e9 < 14.0


def test_old_checkpoint_configs_rebuild_the_model_they_were_trained_as():
    """The config stored in the former demo checkpoint (saved before `full_res_convs` existed)
    rebuilds the former model, not today's default: the same modules and parameter count."""
    old = {
        "widths": [24, 32, 48],
        "kernel_size": 7,
        "refine_width": 16,
        "refine_layers": 3,
        "albedo_eps": 0.01,
        "depth_scale": "log",
        "history_input": True,
        "depth_tolerance": 0.1,
        "normal_threshold": 0.9,
        "min_alpha": 0.2,
        "max_history": 64.0,
    }
    cfg = AFNConfig.from_dict(old)
    assert (cfg.full_res_convs, cfg.full_res_decoder_kernel) == (2, 3)
    assert AFNConfig.from_dict(cfg.to_dict()) == cfg == AFNConfig.from_dict(LEGACY_CONFIG)
    model = build_model("afn", old)
    assert len(model.predictor.encoders[0]) == 4  # conv, relu, conv, relu
    assert parameter_count(model) == 115_830  # the count of the former default (specs table)
    # a config saved with one full-scale option but before the other gets the other's old value
    between = {**old, "full_res_convs": 1}
    assert AFNConfig.from_dict(between).full_res_decoder_kernel == 3
    # a partial config (overrides) gets today's defaults for what it does not name
    partial = AFNConfig.from_dict({"widths": [24, 32, 48]})
    assert (partial.full_res_convs, partial.full_res_decoder_kernel) == (1, 1)
    with pytest.raises(ValueError, match="full_res_convs must be >= 1"):
        AFNConfig.from_dict({"full_res_convs": 0})
    with pytest.raises(ValueError, match="full_res_decoder_kernel must be odd"):
        AFNConfig.from_dict({"full_res_decoder_kernel": 2})


def test_exports_to_onnx_with_custom_nodes_and_dynamic_size(model: AFN):
    """One graph (dynamo, dynamic H and W): the filter stages are rtdenoise custom nodes and ORT
    (fast kernels and portable function bodies) follows PyTorch over moving frames."""
    from rtdenoise.export.matmul_heads import BIAS_ROW_DOC
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate
    from rtdenoise.runtime.denoiser import Denoiser

    proto = export_model(model)
    custom = [n.op_type for n in proto.graph.node if n.domain == "rtdenoise"]
    assert sorted(custom) == [
        "AdaptiveFusion", "SoftmaxKernelApply", "SoftmaxKernelApply", "TemporalAccumulation"
    ]  # fmt: skip
    ops_used = {n.op_type for n in proto.graph.node}
    assert "Conv" in ops_used and "GridSample" not in ops_used
    # the kernels' softmax happens inside SoftmaxKernelApply: its logits come straight from
    # the heads (the 1/2-scale Conv; the full-scale head, split between the logits and the
    # fusion weight, as a MatMul: export/matmul_heads.py), not from a softmax in the graph
    producer = {o: n for n in proto.graph.node for o in n.output}
    logits = [n.input[1] for n in proto.graph.node if n.op_type == "SoftmaxKernelApply"]
    assert sorted(producer[x].op_type for x in logits) == ["Conv", "Reshape"]
    (reshaped,) = [producer[x] for x in logits if producer[x].op_type == "Reshape"]
    assert producer[reshaped.input[0]].doc_string == BIAS_ROW_DOC
    assert "Softmax" not in ops_used
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.family"] == "afn" and meta["rtdenoise.pad_multiple"] == "4"
    data = proto.SerializeToString()
    assert Denoiser(data).contract.declaration == model.declaration()  # export -> parse
    for h, w in ((32, 40), (24, 16)):
        report = validate(model, data, synthetic_frames(model.inputs, 3, h, w))
        assert report.passed and report.max_error < 1e-5, report.errors


def test_fusion_network_sees_the_filtered_images_and_exports():
    """fusion="network" (Lee24 Fig. 2c): alpha from a CNN over d_TA, U D d_TA, U d_1spp and the
    features, not from the predictor's head; it trains (gradients reach it) and exports, ORT
    (fast and portable) following PyTorch over moving frames with state."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate

    torch.manual_seed(0)
    net = build_model("afn", {**SMALL, "fusion": "network", "fusion_width": 6})
    assert net.predictor.head_ta.out_channels == 25 and net.fusion is not None
    assert build_model("afn", SMALL).fusion is None  # the default keeps the head's alpha
    # alpha follows the filtered images: the same features, different d_1spp, different alpha
    d_ta, features = torch.rand(1, 3, 16, 16), torch.rand(1, 7, 16, 16)
    with torch.no_grad():
        a1 = net.fusion(d_ta, torch.rand(1, 3, 8, 8), features)
        a2 = net.fusion(d_ta, torch.rand(1, 3, 8, 8) * 5.0, features)
    assert a1.shape == (1, 1, 16, 16) and not torch.allclose(a1, a2)
    assert float(a1.min()) > 0.0 and float(a1.max()) < 1.0
    out, _ = net(_buffers(), net.initial_state(N, H, W), torch.tensor(1.0))
    out.mean().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.fusion.parameters())
    net = net.eval().requires_grad_(False)
    data = export_model(net).SerializeToString()
    report = validate(net, data, synthetic_frames(net.inputs, 3, 32, 24))
    assert report.passed and report.max_error < 1e-5, report.errors
