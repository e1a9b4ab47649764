"""The NBG model (Meng20): GuideNet input and outputs, the three grids and their composition
(eq. (15)), temporal accumulation with history weight 0.8, the eq. (14) loss, outlier
suppression, export with validation against ONNX Runtime."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch
from model_inputs import random_buffers

from rtdenoise.models.base import parameter_count
from rtdenoise.models.families.nbg import NBG, NBGConfig, gamma_map, suppress_outliers
from rtdenoise.models.ops import observe_calls
from rtdenoise.models.ops.bilateral_grid import bilateral_grid
from rtdenoise.models.registry import build_model, default_config, families

N, H, W = 2, 24, 20


def _buffers(seed: int = 0, n: int = N, h: int = H, w: int = W) -> dict[str, torch.Tensor]:
    return {k: v for k, v in random_buffers(seed, n, h, w).items() if k != "color_b"}


def _record(calls: list):
    """Observer keeping the grid calls (the history warp, Reproject, is not a grid)."""

    def record(op, inputs, attrs, ms):
        if op.name == "BilateralGrid":
            calls.append((op.name, [x.detach().clone() for x in inputs], dict(attrs)))

    return record


def test_fixed_guidenet_outputs_give_the_eq15_blend_of_three_grids():
    """GuideNet weights 0 and chosen biases: guides 255 sigmoid(b_k), weights sigmoid(b_3),
    sigmoid(b_4); the output is (w1 R1 + w2 R2 + (1 - w1 - w2) R3) * (albedo + eps), R_k the
    grids (4, 64), (8, 32), (16, 16) of the irradiance with those guides."""
    m = NBG().eval()
    bias = torch.tensor([-1.0, 0.5, 2.0, 0.3, -0.7])
    with torch.no_grad():
        for p in m.parameters():
            p.zero_()
        m.guide_net.conv2.bias.copy_(bias)
    b = _buffers(1)
    calls: list = []
    with torch.no_grad(), observe_calls(_record(calls)):
        out, _ = m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    modulation = b["albedo"] + m.cfg.albedo_eps
    r = b["color"] / modulation  # reset: r_TA = this frame's irradiance
    sig = torch.sigmoid(bias)
    assert [(name, a["cell_size"], a["grid_depth"]) for name, _, a in calls] == [
        ("BilateralGrid", 4, 64),
        ("BilateralGrid", 8, 32),
        ("BilateralGrid", 16, 16),
    ]
    grids = []
    for k, (_, (image, guide), attrs) in enumerate(calls):
        torch.testing.assert_close(image, r)
        torch.testing.assert_close(guide, torch.full((N, 1, H, W), 255.0 * float(sig[k])))
        grids.append(bilateral_grid(r, guide, attrs["cell_size"], attrs["grid_depth"]))
    w1, w2 = float(sig[3]), float(sig[4])
    expected = (w1 * grids[0] + w2 * grids[1] + (1.0 - w1 - w2) * grids[2]).clamp(min=0.0)
    torch.testing.assert_close(out, expected * modulation, rtol=1e-5, atol=1e-5)


def test_guidenet_input_is_gamma_mapped_radiance_and_features():
    m = NBG({"hidden": 4}).eval()
    seen = {}
    m.guide_net.register_forward_pre_hook(lambda _, args: seen.update(net_in=args[0]))
    b = _buffers(2)
    b["color"][:, :, :3] = 9.0  # > 1 after gamma: clipped to 1 (official tone_mapping)
    with torch.no_grad():
        m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    net_in = seen["net_in"]
    assert net_in.shape == (N, 10, H, W)
    torch.testing.assert_close(net_in[:, :3], (b["color"].clamp(1e-8) ** (1 / 2.2)).clamp(max=1.0))
    assert float(net_in[:, :3].max()) == 1.0
    torch.testing.assert_close(net_in[:, 3:6], b["albedo"])
    torch.testing.assert_close(net_in[:, 6:9], 0.5 * (b["normal"] + 1.0))
    depth = torch.log1p(b["depth"])
    torch.testing.assert_close(net_in[:, 9:], depth / depth.amax(dim=(1, 2, 3), keepdim=True))


def test_log1p_guide_input_keeps_a_light_apart_from_a_white_wall():
    """guide_tonemap "log1p": GuideNet reads log1p(radiance), not clipped: a pixel of 9 and
    one of 1 differ (under Meng20's S both are 1)."""
    m = NBG({"hidden": 4, "guide_tonemap": "log1p"}).eval()
    seen = {}
    m.guide_net.register_forward_pre_hook(lambda _, args: seen.update(net_in=args[0]))
    b = _buffers(2)
    b["color"][:, :, :3] = 9.0
    b["color"][:, :, 3:6] = 1.0
    with torch.no_grad():
        m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    net_in = seen["net_in"]
    torch.testing.assert_close(net_in[:, :3], torch.log1p(b["color"]))
    assert float(net_in[:, :3, :3].min()) == pytest.approx(np.log(10.0))
    assert float(net_in[:, :3, 3:6].max()) == pytest.approx(np.log(2.0))
    with pytest.raises(ValueError, match="guide_tonemap"):
        NBGConfig.from_dict({"guide_tonemap": "filmic"})


def test_temporal_accumulation_keeps_history_weight_0_8():
    """A static camera and a converged history (length 10): the grids filter
    0.2 x current + 0.8 x history (Meng20 s.4.6)."""
    m = NBG({"hidden": 4}).eval()
    assert m.cfg.min_alpha == 0.2
    b = dict(_buffers(3), motion=torch.zeros(N, 2, H, W))
    current = b["color"] / (b["albedo"] + m.cfg.albedo_eps)
    history = torch.rand(N, 3, H, W) * 2.0
    state = {
        "ta": torch.cat((history, torch.full((N, 1, H, W), 10.0)), 1),
        "geometry": torch.cat((b["normal"], b["depth"]), 1),
    }
    calls: list = []
    with torch.no_grad(), observe_calls(_record(calls)):
        m(b, state, torch.tensor(0.0))
    torch.testing.assert_close(calls[0][1][0], 0.2 * current + 0.8 * history)


def test_loss_is_eq14_l1_of_gamma_mapped_images():
    m = NBG({"hidden": 4})
    g = torch.Generator().manual_seed(4)
    out = torch.rand(2, 3, 3, 8, 8, generator=g) * 2.0
    ref = torch.rand(2, 3, 3, 8, 8, generator=g) * 2.0
    out[0, 0, :, :2] = 0.0  # black pixels: finite gradient
    out[0, 1, :, :2] = -1.0  # negative: S = S(0)

    def s(x):
        return np.clip(np.maximum(x, 1e-8) ** (1 / 2.2), 0.0, 1.0)

    o, r = out.numpy().astype(np.float64), ref.numpy().astype(np.float64)
    expected = np.abs(s(o) - s(r)).mean()
    assert float(m.loss(out, ref, 0.0)) == pytest.approx(expected, rel=1e-5)
    d_o, d_r = np.diff(s(o), axis=1), np.diff(s(r), axis=1)
    with_t = expected + 0.5 * np.abs(d_o - d_r).mean()
    assert float(m.loss(out, ref, 0.5)) == pytest.approx(with_t, rel=1e-5)
    out.requires_grad_(True)
    m.loss(out, ref, 0.25).backward()
    assert torch.isfinite(out.grad).all()
    assert float(gamma_map(torch.tensor(4.0), 2.2)) == 1.0


def test_outlier_suppression_replaces_fireflies_only():
    color = torch.ones(1, 3, 12, 12)
    color[..., 5, 5] = 1000.0  # firefly on a flat surface
    color[..., 8, :] = 3.0  # a bright row: every pixel has similar neighbours in it
    albedo = torch.full((1, 3, 12, 12), 0.5)
    normal = torch.zeros(1, 3, 12, 12)
    normal[:, 2] = 1.0
    cfg = NBGConfig(outlier_suppression=True)
    out = suppress_outliers(color, albedo, normal, cfg)
    assert torch.allclose(out[..., 5, 5], torch.ones(3))  # mean of its 8 neighbours
    mask = torch.ones(12, 12, dtype=torch.bool)
    mask[5, 5] = False
    assert torch.equal(out[..., mask], color[..., mask])
    # the same firefly on a pixel whose albedo differs from all neighbours: no similar
    # neighbours, kept
    albedo[..., 5, 5] = 0.0
    assert float(suppress_outliers(color, albedo, normal, cfg)[0, 0, 5, 5]) == 1000.0
    m = NBG({"hidden": 4, "outlier_suppression": True}).eval()
    b = _buffers(5)
    b["color"][:, :, 3, 3] = 1e4
    with torch.no_grad():
        out, _ = m(b, m.initial_state(N, H, W), torch.tensor(1.0))
    assert torch.isfinite(out).all()


def test_registry_config_and_size():
    assert "nbg" in families()
    cfg = default_config("nbg")
    assert cfg["cell_sizes"] == [4, 8, 16] and cfg["grid_depths"] == [64, 32, 16]
    assert cfg["hidden"] == 20 and cfg["kernel_size"] == 5 and cfg["min_alpha"] == 0.2
    m = build_model("nbg")
    assert m.config() == cfg and NBG(cfg).config() == cfg
    # 5 x 5 conv 10 -> 20 and 20 -> 5 with biases (Meng20 Fig. 2 left)
    assert parameter_count(m) == 25 * 10 * 20 + 20 + 25 * 20 * 5 + 5 == 7525
    one = build_model("nbg", {"cell_sizes": [8], "grid_depths": [32]})
    assert one.guide_net.conv2.out_channels == 1  # one guide, no weight
    with pytest.raises(ValueError, match="equal length"):
        NBGConfig.from_dict({"cell_sizes": [4, 8]})
    with pytest.raises(ValueError, match="init"):
        NBGConfig.from_dict({"init": "he"})
    with pytest.raises(ValueError, match="unknown nbg config keys"):
        build_model("nbg", {"grids": 3})


def test_exports_three_grid_nodes_and_matches_ort_over_eight_frames():
    """One BilateralGrid node per grid; ORT (fast kernels and portable function bodies)
    follows PyTorch over a committed 8-frame sequence with state fed back, and over a synthetic
    sequence whose size is not a multiple of any s. With outlier suppression on (the default
    configuration's export is checked on the shipped demo, tests/test_demo_models.py)."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import synthetic_frames, validate
    from rtdenoise.models.data import load_sequence
    from rtdenoise.runtime.denoiser import Denoiser
    from rtdenoise.shipped import sample_sequences

    torch.manual_seed(0)
    model = build_model("nbg", {"outlier_suppression": True}).eval()
    proto = export_model(model)
    nodes = [n for n in proto.graph.node if n.domain == "rtdenoise"]
    assert [(n.op_type, {a.name: a.i for a in n.attribute}) for n in nodes] == [
        ("TemporalAccumulation", {"per_tap": 0})  # the history warp and blend (bilinear)
    ] + [
        ("BilateralGrid", {"cell_size": s, "grid_depth": d})
        for s, d in zip(model.cfg.cell_sizes, model.cfg.grid_depths, strict=True)
    ]
    functions = sorted(f.name for f in proto.functions if f.domain == "rtdenoise")
    assert functions == ["BilateralGrid", "TemporalAccumulation"]
    meta = {p.key: p.value for p in proto.metadata_props}
    assert meta["rtdenoise.family"] == "nbg" and meta["rtdenoise.pad_multiple"] == "1"

    data = proto.SerializeToString()
    assert Denoiser(data).contract.declaration == model.declaration()
    seq = load_sequence(sample_sequences()[0], model.inputs)
    frames = [{k: v[i] for k, v in seq.buffers.items()} for i in range(seq.frames)]
    assert len(frames) == 8 and np.any(frames[1]["motion"] != 0)
    report = validate(model, data, frames, tolerance=1e-4)
    assert report.passed, report.errors
    assert set(report.errors) == {"ort_fast", "ort_portable"}
    assert all(len(v) == 8 for v in report.errors.values())
    synthetic = synthetic_frames(model.inputs, 3, 21, 34)
    for frame in synthetic:
        frame["color"][:, 5, 5] = 500.0  # a firefly for the outlier test
    report = validate(model, data, synthetic)
    assert report.passed, report.errors


def assert_exports_over_committed(model: NBG) -> None:
    """ORT (fast and portable) follows `model`'s export within 1e-4 over the first committed
    sequence, 8 frames with state fed back."""
    from rtdenoise.export.onnx_export import export_model
    from rtdenoise.export.validate import validate
    from rtdenoise.models.data import load_sequence
    from rtdenoise.shipped import sample_sequences

    data = export_model(model).SerializeToString()
    seq = load_sequence(sample_sequences()[0], model.inputs)
    frames = [{k: v[i] for k, v in seq.buffers.items()} for i in range(seq.frames)]
    report = validate(model, data, frames, tolerance=1e-4)
    assert report.passed, report.errors
    assert set(report.errors) == {"ort_fast", "ort_portable"}


def test_middle_layers_deepen_guidenet_and_export():
    """`middle_layers` hidden -> hidden convs (k = middle_kernel_size, leaky ReLU) between
    GuideNet's two: their parameters, their effect on the guides, and an export that ORT
    (fast and portable) follows over a committed 8-frame sequence."""
    torch.manual_seed(0)
    m = NBG({"hidden": 6, "middle_layers": 2, "middle_kernel_size": 3}).eval()
    plain = 25 * 10 * 6 + 6 + 25 * 6 * 5 + 5
    assert parameter_count(m) == plain + 2 * (9 * 6 * 6 + 6)
    assert [c.kernel_size for c in m.guide_net.middle] == [(3, 3), (3, 3)]
    x = torch.rand(1, 10, 12, 14)
    with torch.no_grad():
        guides = m.guide_net(x)
        m.guide_net.middle[1].weight.zero_()
        m.guide_net.middle[1].bias.fill_(0.5)  # the second middle conv outputs a constant
        flat = m.guide_net(x)
    assert float((guides - flat).abs().max()) > 1e-3
    inner = flat[:, :, 2:-2, 2:-2]  # (conv2's zero padding shapes the 2-pixel border)
    assert float(inner.std(dim=(2, 3)).max()) < 1e-6  # nothing of x reaches conv2 any more
    assert NBG({"hidden": 6}).state_dict().keys() <= m.state_dict().keys()  # Meng20's names
    with pytest.raises(ValueError, match="middle_layers"):
        NBGConfig.from_dict({"middle_layers": -1})
    with pytest.raises(ValueError, match="middle_kernel_size"):
        NBGConfig.from_dict({"middle_kernel_size": 2})

    torch.manual_seed(0)
    model = NBG({"middle_layers": 1}).eval()
    assert_exports_over_committed(model)


def test_pointwise_guide_is_a_per_pixel_path_and_exports():
    """`pointwise_guide`: a 1 x 1 conv from GuideNet's input added before the sigmoid, zero at
    init (the same guides as without it, under one seed); with the k x k path made constant the
    guides are sigmoid(b + W x) pixel by pixel; an export ORT (fast and portable) follows over a
    committed 8-frame sequence with the path trained away from 0."""
    torch.manual_seed(0)
    plain = NBG({"hidden": 6}).eval()
    torch.manual_seed(0)
    m = NBG({"hidden": 6, "pointwise_guide": True}).eval()
    assert parameter_count(m) == parameter_count(plain) + 10 * 5 + 5
    x = torch.rand(1, 10, 12, 14)
    with torch.no_grad():
        assert torch.equal(m.guide_net(x), plain.guide_net(x))
        pw = m.guide_net.pointwise
        pw.weight.normal_(0.0, 1.0)
        pw.bias.normal_(0.0, 1.0)
        m.guide_net.conv2.weight.zero_()  # the k x k path: its bias alone
        expected = torch.sigmoid(
            m.guide_net.conv2.bias.view(1, 5, 1, 1)
            + torch.einsum("oc,nchw->nohw", pw.weight[:, :, 0, 0], x)
            + pw.bias.view(1, 5, 1, 1)
        )
        assert float((m.guide_net(x) - expected).abs().max()) < 1e-6
    assert plain.state_dict().keys() < m.state_dict().keys()  # Meng20's names kept

    torch.manual_seed(1)
    model = NBG({"pointwise_guide": True}).eval()
    with torch.no_grad():
        model.guide_net.pointwise.weight.normal_(0.0, 0.5)
    assert_exports_over_committed(model)


def _outputs(model, restart_every_frame: bool = False, *, frames: list[dict]) -> torch.Tensor:
    """(T, ...) outputs of `model` over `frames`, its state carried (reset on the first frame,
    or on every frame)."""
    state = model.initial_state(1, *frames[0]["color"].shape[-2:])
    outs = []
    for i, frame in enumerate(frames):
        reset = torch.tensor(1.0 if i == 0 or restart_every_frame else 0.0)
        out, state = model(frame, state, reset)
        outs.append(out)
    return torch.stack(outs)


def test_history_gate_filters_between_the_frame_and_its_history_and_exports():
    """`history_gate`: GuideNet reads S(color) too (13 channels) and outputs a gate b; the grids
    filter r + b (r_TA - r). With guides that read no radiance, b = 1 gives the ungated model's
    output, b = 0 that of the ungated model restarted every frame; an export ORT (fast and
    portable) follows over a committed 8-frame sequence with state."""
    from rtdenoise.models.data import load_sequence
    from rtdenoise.shipped import sample_sequences

    torch.manual_seed(0)
    gated = NBG({"hidden": 6, "history_gate": True}).eval()
    plain = NBG({"hidden": 6}).eval()
    assert gated.guide_net.conv1.in_channels == 13 and gated.guide_net.conv2.out_channels == 6
    seq = load_sequence(sample_sequences()[0], gated.inputs)
    frames = [{k: torch.from_numpy(v[i : i + 1]) for k, v in seq.buffers.items()} for i in range(3)]
    run = functools.partial(_outputs, frames=frames)

    with torch.no_grad():  # guides from albedo, normal, depth only (the same with or without
        # history); the gated k x k path's weights as plain's, the frame's channels 0
        plain.guide_net.conv1.weight[:, :3] = 0.0
        c1 = gated.guide_net.conv1.weight
        c1.zero_()
        c1[:, :10] = plain.guide_net.conv1.weight
        gated.guide_net.conv1.bias.copy_(plain.guide_net.conv1.bias)
        gated.guide_net.conv2.weight.zero_()
        gated.guide_net.conv2.weight[:5] = plain.guide_net.conv2.weight
        gated.guide_net.conv2.bias[:5] = plain.guide_net.conv2.bias
        for logit, expected in ((60.0, run(plain)), (-60.0, run(plain, True))):
            gated.guide_net.conv2.bias[5] = logit  # b = 1, then b = 0
            got = run(gated)
            assert float((got - expected).abs().max()) < 1e-4 * (1 + float(expected.abs().max()))
        assert float((run(plain) - run(plain, True)).abs().max()) > 1e-2  # the history matters

    torch.manual_seed(1)
    model = NBG({"history_gate": True, "pointwise_guide": True}).eval()
    with torch.no_grad():
        model.guide_net.pointwise.weight.normal_(0.0, 0.5)
    assert_exports_over_committed(model)


def test_history_input_grows_guidenet_from_a_checkpoint_and_exports(tmp_path):
    """`history_input`: GuideNet reads TA's current-frame weight as a last channel (11 inputs
    without the gate). Fine-tuning a checkpoint with it on (`initial_weights`) starts that channel
    at zero, so the grown model gives the checkpoint's outputs over frames with history; once the
    channel has weight, frames with and without history differ by more than before. Exports."""
    from rtdenoise.models.checkpoint import save_checkpoint
    from rtdenoise.models.data import load_sequence
    from rtdenoise.models.train import initial_weights
    from rtdenoise.shipped import sample_sequences

    torch.manual_seed(0)
    plain = NBG({"hidden": 6}).eval()
    path = save_checkpoint(tmp_path / "plain.pt", plain)
    grown, _ = initial_weights(path, "nbg", {"history_input": True})
    grown.eval()
    assert grown.guide_net.conv1.in_channels == 11
    assert float(grown.guide_net.conv1.weight.detach()[:, 10].abs().max()) == 0.0
    seq = load_sequence(sample_sequences()[0], plain.inputs)
    frames = [{k: torch.from_numpy(v[i : i + 1]) for k, v in seq.buffers.items()} for i in range(3)]
    run = functools.partial(_outputs, frames=frames)

    with torch.no_grad():
        torch.testing.assert_close(run(grown), run(plain))
        grown.guide_net.conv1.weight[:, 10].normal_(0.0, 2.0)
        assert float((run(grown)[1:] - run(plain)[1:]).abs().max()) > 1e-3  # it reads the weight
    with pytest.raises(Exception, match="changes the weights"):
        initial_weights(path, "nbg", {"hidden": 8})
    torch.manual_seed(1)
    assert_exports_over_committed(NBG({"history_gate": True, "history_input": True}).eval())
