"""The affinity model (Isik21) beyond the shared contract tests: the paper's size, the pipeline
(embedding over a dynamic number of samples, nearest warp, accumulation, the kernels through
the custom ops), export and ORT (fast and portable) against PyTorch over 8 frames with state,
the run-time kernel size (Denoiser overrides, `denoise-run --kernel-size`), the losses."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from model_inputs import random_buffers, samples_of

from rtdenoise.models.families.affinity import (
    Affinity,
    AffinityConfig,
    Embedding,
    parameter_count,
    smape_l1,
    warp_nearest,
)
from rtdenoise.models.ops import observe_calls
from rtdenoise.models.registry import build_model, default_config
from rtdenoise.runtime.errors import InputError

N, H, W = 1, 20, 24


@pytest.fixture(scope="module")
def model() -> Affinity:
    torch.manual_seed(0)
    return build_model("affinity", Affinity.example_config).eval().requires_grad_(False)


def _buffers(seed: int, s: int = 2, n: int = N, h: int = H, w: int = W):
    b = random_buffers(seed, n, h, w)
    return {"samples": samples_of(b, s), "motion": b["motion"]}


def test_paper_size_and_parameter_count():
    cfg = default_config("affinity")
    assert cfg["encoder"] == [64, 64, 64, 80] and cfg["bottleneck"] == 96
    assert cfg["decoder"] == [80, 64, 64, 32] and cfg["kernel_size"] == 13
    m = build_model("affinity")
    assert m.pad_multiple == 16
    assert AffinityConfig().parameter_channels == 32  # K (d + 2) + 2 = the paper's last c32
    assert parameter_count(m.unet) == 938_944
    # Isik21 "0.94 M": with its 18 per-sample features the FC net has 2,720 parameters
    assert parameter_count(Embedding(18, 32, 3, 0.01)) == 2_720
    assert parameter_count(m.embedding) == 10 * 32 + 32 + 2 * (32 * 32 + 32)  # 10 features
    with pytest.raises(ValueError, match="kernel_size must be an odd integer"):
        AffinityConfig.from_dict({"kernel_size": 12})
    with pytest.raises(ValueError, match="must include 'color'"):
        AffinityConfig.from_dict({"sample_features": ["albedo", "normal"]})


def test_warp_is_nearest_neighbour_at_previous_position():
    prev = torch.arange(2 * 5 * 7, dtype=torch.float32).reshape(1, 2, 5, 7)
    motion = torch.zeros(1, 2, 5, 7)
    motion[:, 0] = 1.4  # previous x = x + 1.4 -> nearest x + 1
    motion[:, 1] = -0.6  # previous y = y - 0.6 -> nearest y - 1
    warped, inside = warp_nearest(prev, motion)
    p = prev.numpy()
    for y in range(5):
        for x in range(7):
            ok = 0 <= y - 1 and x + 1 < 7
            assert bool(inside[0, 0, y, x]) == ok
            if ok:
                np.testing.assert_array_equal(warped[0, :, y, x].numpy(), p[0, :, y - 1, x + 1])


def test_pipeline_calls_the_affinity_kernels(model: Affinity):
    calls = []
    with observe_calls(lambda op, inputs, attrs, ms: calls.append((op.name, dict(attrs)))):
        model(_buffers(0), model.initial_state(N, H, W), torch.tensor(1.0))
    # one nearest-neighbour Reproject per state tensor (the history warp, Isik21 W_t), then
    # K = 3: two spatial kernels at dilation 1 and 2, the last with the temporal one at 4
    warps = [attrs for name, attrs in calls if name == "Reproject"]
    assert warps == [{"nearest": 1}] * len(model.state_specs)
    kernels = [(name, attrs["dilation"]) for name, attrs in calls if name != "Reproject"]
    assert kernels == [("AffinityFilter", 1), ("AffinityFilter", 2), ("TemporalAffinityFilter", 4)]


def test_embedding_averages_samples_and_any_sample_count_runs(model: Affinity):
    one = _buffers(1, s=1)
    dup = {"samples": one["samples"].repeat(1, 3, 1, 1, 1), "motion": one["motion"]}
    state = model.initial_state(N, H, W)
    out1, _ = model(one, state, torch.tensor(1.0))
    out3, _ = model(dup, state, torch.tensor(1.0))
    torch.testing.assert_close(out1, out3, rtol=1e-5, atol=1e-6)  # eq. (1): a mean over S
    four = _buffers(1, s=4)  # same mean radiance, other samples: another embedding
    out4, _ = model(four, state, torch.tensor(1.0))
    assert torch.isfinite(out4).all()
    e1, e4 = (model.embedding(model._network_samples(b["samples"])) for b in (one, four))
    assert float((e1 - e4).abs().max()) > 1e-3


def test_accumulation_uses_lambda_and_history(model: Affinity):
    b = _buffers(2)
    static = dict(b, motion=torch.zeros(N, 2, H, W))
    _, first = model(static, model.initial_state(N, H, W), torch.tensor(1.0))
    radiance = b["samples"][:, :, :3].mean(dim=1)
    torch.testing.assert_close(first["radiance"], radiance)  # reset: L_bar = L (eq. (5))
    history = dict(first, radiance=first["radiance"] + 10.0)
    _, nxt = model(static, history, torch.tensor(0.0))
    lam = (nxt["radiance"] - radiance) / 10.0  # L_bar = (1 - lambda) L + lambda W L_bar
    assert float(lam.min()) > 0.0 and float(lam.max()) < 1.0


@pytest.fixture(scope="module")
def exported(model: Affinity) -> bytes:
    from rtdenoise.export.onnx_export import export_model

    proto = export_model(model)
    custom = sorted(n.op_type for n in proto.graph.node if n.domain == "rtdenoise")
    warps = ["Reproject"] * len(model.state_specs)  # the history, one op per state tensor
    assert custom == ["AffinityFilter", "AffinityFilter", *warps, "TemporalAffinityFilter"]
    ops = {n.op_type for n in proto.graph.node}
    assert {"ReduceMean", "MaxPool", "Resize"} <= ops
    assert not {"GatherElements", "Expand"} & ops  # no gather spelled out at full resolution
    assert "option.kernel_size" in [i.name for i in proto.graph.input]
    return proto.SerializeToString()


def _frames(model: Affinity, n: int, s: int, h: int = 24, w: int = 28):
    from rtdenoise.export.validate import synthetic_frames

    return synthetic_frames(
        model.inputs, n, h, w, sample_features=model.cfg.sample_features, samples=s
    )


@pytest.mark.parametrize("samples", [3, 1])
def test_onnx_fast_and_portable_follow_pytorch_over_eight_frames(model, exported, samples):
    from rtdenoise.export.validate import validate
    from rtdenoise.runtime.denoiser import Denoiser

    assert Denoiser(exported).contract.declaration == model.declaration()
    report = validate(model, exported, _frames(model, 8, samples), tolerance=1e-4)
    assert report.passed and all(len(e) == 8 for e in report.errors.values()), report.errors


def test_kernel_size_is_a_run_time_option(model, exported):
    """Isik21 3.6: the model trained (here: built) at k = 5 runs at 7 and 19 without re-export,
    on the fast and the portable path, as PyTorch with the same kernel size does."""
    from rtdenoise.export.validate import torch_outputs
    from rtdenoise.runtime.denoiser import Denoiser

    frames = _frames(model, 3, 2)
    outs = {}
    for k in (7, 19):
        ref = torch_outputs(_with_kernel_size(model, k), frames)
        for fast in (True, False):
            d = Denoiser(exported, fast_kernels=fast, overrides={"kernel_size": k})
            assert d.options == {"kernel_size": float(k)}
            outs[k] = [d.process(f) for f in frames]
            for out, r in zip(outs[k], ref, strict=True):
                assert np.isfinite(out).all() and float(np.abs(out - r).max()) < 1e-4
    assert float(np.abs(outs[7][-1] - outs[19][-1]).max()) > 1e-2
    assert Denoiser(exported).options == {"kernel_size": 5.0}
    with pytest.raises(InputError, match="odd integer in \\[1, 63\\], got 8"):
        Denoiser(exported, overrides={"kernel_size": 8})
    with pytest.raises(InputError, match="no run-time option 'size'.*options: kernel_size"):
        Denoiser(exported, overrides={"size": 7})


def _with_kernel_size(model: Affinity, k: int) -> Affinity:
    copy = build_model("affinity", model.config()).eval()
    copy.load_state_dict(model.state_dict())
    copy.option_kernel_size.fill_(float(k))
    return copy


def test_denoise_run_kernel_size_flag(model, exported, tmp_path):
    from typer.testing import CliRunner

    from rtdenoise.cli.run import app
    from rtdenoise.runtime.sequences.frames import read_exr
    from rtdenoise.shipped import sample_sequences

    onnx_path = tmp_path / "affinity.onnx"
    onnx_path.write_bytes(exported)
    seq = sample_sequences()[0]
    results = {}
    for k in (7, 19):
        out = tmp_path / f"k{k}"
        res = CliRunner().invoke(
            app, [str(seq), "-o", str(out), "--model", str(onnx_path), "--kernel-size", str(k)]
        )
        assert res.exit_code == 0, res.output
        ch = read_exr(out / "frame_0007.exr")
        results[k] = np.stack([ch[c] for c in "RGB"])
        assert np.isfinite(results[k]).all()
    assert float(np.abs(results[7] - results[19]).max()) > 1e-2
    res = CliRunner().invoke(
        app,
        [str(seq), "-o", str(tmp_path / "bad"), "--model", str(onnx_path), "--kernel-size", "6"],
    )
    assert res.exit_code == 2 and "odd integer" in res.output


def test_loss_is_eq_9_with_the_bandwidth_regulariser():
    torch.manual_seed(3)
    m = build_model("affinity", Affinity.example_config).train()
    out = torch.tensor([[[[[1.0]], [[2.0]], [[3.0]]]]])  # (1, 1, 3, 1, 1)
    ref = torch.tensor([[[[[2.0]], [[2.0]], [[1.0]]]]])
    # eq. (11): (1/3) * (1 + 0 + 2) / (6 + 5 + 0.01)
    torch.testing.assert_close(smape_l1(out, ref, 0.01), torch.tensor(3.0 / 11.01 / 3.0))
    assert float(m.loss(out, ref, 0.25)) == pytest.approx(3.0 / 11.01 / 3.0)  # T = 1, no reg
    state = m.initial_state(N, H, W)
    outs = []
    for t in range(2):
        o, state = m(_buffers(t), state, torch.tensor(1.0 if t == 0 else 0.0))
        outs.append(o)
    outs = torch.stack(outs, dim=1)
    refs = outs.detach() * 1.1
    assert len(m._bandwidths) == 2
    reg = torch.stack(m._bandwidths).mean()
    expected = smape_l1(outs, refs, 0.01) + 0.25 * smape_l1(
        outs[:, 1:] - outs[:, :-1], refs[:, 1:] - refs[:, :-1], 0.01
    )
    loss = m.loss(outs, refs, 0.25)
    torch.testing.assert_close(loss, expected + 1e-5 * reg)
    assert m._bandwidths == []  # consumed
    loss.backward()
    assert m.unet.up[-1][-1].weight.grad is not None


@pytest.mark.parametrize("name", ["smape", "l1-ms-ssim"])
def test_another_training_loss_keeps_the_bandwidth_regulariser(name):
    """`denoise-train --loss` other than the paper's still adds Isik21 eq. (13)."""
    from rtdenoise.models.losses import LOSSES, training_loss

    torch.manual_seed(3)
    m = build_model("affinity", Affinity.example_config).train()
    state = m.initial_state(N, H, W)
    outs = []
    for t in range(2):
        o, state = m(_buffers(t), state, torch.tensor(1.0 if t == 0 else 0.0))
        outs.append(o)
    outs = torch.stack(outs, dim=1)
    refs = outs.detach() * 1.1 + 0.05
    reg = 1e-5 * torch.stack(m._bandwidths).mean()
    plain = LOSSES[name](outs, refs, 0.25)
    torch.testing.assert_close(training_loss(name, m)(outs, refs, 0.25), plain + reg)
    assert m._bandwidths == [] and float(reg.detach()) > 0
