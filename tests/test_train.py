"""Training: data loading / clips, a short run that learns, exact resume, the CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from train_data import INPUTS, TINY, write_sequence
from typer.testing import CliRunner

from rtdenoise.cli.train import app
from rtdenoise.models.checkpoint import load_checkpoint, read_checkpoint
from rtdenoise.models.data import ClipSampler, load_sequence
from rtdenoise.models.losses import sequence_loss, smape, temporal_smape
from rtdenoise.models.registry import build_model
from rtdenoise.models.train import TrainSettings, train, unroll
from rtdenoise.shipped import demo_model


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory) -> Path:
    return write_sequence(tmp_path_factory.mktemp("data") / "seq_a")


def _settings(steps: int, **kw) -> TrainSettings:
    base = dict(steps=steps, crop=24, frames=3, batch=2, lr=1e-2, seed=3, save_every=0, threads=1)
    return TrainSettings(**{**base, **kw})


def test_losses_match_their_definitions():
    a = torch.tensor([[[[1.0]], [[2.0]], [[0.0]]]])  # (1, 3, 1, 1)
    b = torch.tensor([[[[3.0]], [[2.0]], [[0.0]]]])
    expected = (2.0 / (4.0 + 1e-3) + 0.0 + 0.0) / 3.0  # Lee24 eq. (5)
    assert abs(float(smape(a, b)) - expected) < 1e-7
    seq_a = torch.stack([a, 2 * a], dim=1)  # (N, T, C, H, W)
    seq_b = torch.stack([b, b], dim=1)
    # frame differences: a -> (1, 2, 0), b -> (0, 0, 0) -> per channel 1 / (1 + eps), ...
    d = (1.0 / (1.0 + 1e-3) + 2.0 / (2.0 + 1e-3) + 0.0) / 3.0
    assert abs(float(temporal_smape(seq_a, seq_b)) - d) < 1e-6
    total = float(sequence_loss(seq_a, seq_b, temporal_weight=0.5))
    assert abs(total - (float(smape(seq_a, seq_b)) + 0.5 * d)) < 1e-6
    assert float(temporal_smape(seq_a[:, :1], seq_b[:, :1])) == 0.0


def test_load_sequence_and_clips(seq_dir):
    seq = load_sequence(seq_dir, INPUTS)
    assert seq.frames == 6 and seq.size == (32, 32)
    assert seq.buffers["motion"].shape == (6, 2, 32, 32) and seq.reference.shape == (6, 3, 32, 32)
    assert float(seq.buffers["motion"][:, 0].min()) == 1.0
    sampler = ClipSampler(
        [seq],
        np.random.default_rng(0),
        frames=4,
        crop=30,
        batch=3,
        multiple=4,
        brightness=(2.0, 2.0),
    )
    assert sampler.crop == 28 and sampler.frames == 4
    batch = sampler.sample()
    assert batch.buffers["color"].shape == (3, 4, 3, 28, 28)
    assert batch.reference.shape == (3, 4, 3, 28, 28)
    # flips keep |motion.x| = 1 and motion.y = 0 on this pan
    np.testing.assert_array_equal(batch.buffers["motion"][:, :, 0].abs().numpy(), 1.0)
    np.testing.assert_array_equal(batch.buffers["motion"][:, :, 1].numpy(), 0.0)
    # a clip covering the whole sequence: brightness scales radiance and reference only
    whole = ClipSampler(
        [seq],
        np.random.default_rng(1),
        frames=6,
        crop=32,
        batch=1,
        flips=False,
        brightness=(2.0, 2.0),
    ).sample()
    np.testing.assert_array_equal(whole.buffers["color"][0].numpy(), 2 * seq.buffers["color"])
    np.testing.assert_array_equal(whole.reference[0].numpy(), 2 * seq.reference)
    np.testing.assert_array_equal(whole.buffers["albedo"][0].numpy(), seq.buffers["albedo"])
    # the whole sequence is shorter than --frames: clips take the whole sequence
    assert ClipSampler([seq], np.random.default_rng(0), frames=50).frames == 6


def _fixed_loss(model, seq) -> tuple[float, float]:
    """(SMAPE, temporal SMAPE) of the model over the whole sequence (no augmentation)."""
    bufs = {k: torch.from_numpy(v).unsqueeze(0) for k, v in seq.buffers.items()}
    ref = torch.from_numpy(seq.reference).unsqueeze(0)
    with torch.no_grad():
        out = unroll(model.eval(), bufs)
    return float(smape(out, ref)), float(temporal_smape(out, ref))


def test_short_run_lowers_the_loss(seq_dir, tmp_path):
    seq = load_sequence(seq_dir, INPUTS)
    torch.manual_seed(3)  # train() seeds torch with settings.seed = 3 before building
    s0, t0 = _fixed_loss(build_model("afn", TINY), seq)
    settings = _settings(40, crop=32, frames=4)
    result = train(
        [seq_dir], tmp_path / "m.pt", model_config=TINY, settings=settings, progress=False
    )
    assert result.step == 40 and len(result.losses) == 40
    model, meta = load_checkpoint(tmp_path / "m.pt")
    s1, t1 = _fixed_loss(model, seq)
    print(f"whole-sequence SMAPE {s0:.4f} -> {s1:.4f}, temporal SMAPE {t0:.4f} -> {t1:.4f}")
    # measured: SMAPE 0.311 -> 0.194, total (SMAPE + 0.25 temporal) 0.517 -> 0.370
    assert s1 < 0.7 * s0
    assert s1 + 0.25 * t1 < 0.8 * (s0 + 0.25 * t0)
    assert np.mean(result.losses[-5:]) < 0.85 * np.mean(result.losses[:5])
    assert meta["step"] == 40 and meta["seed"] == 3 and meta["data"] == [str(seq_dir)]
    assert meta["loss_history"][-1][0] == 40 and meta["torch"] == str(torch.__version__)


def test_resume_equals_uninterrupted_run(seq_dir, tmp_path):
    full = train(
        [seq_dir], tmp_path / "full.pt", model_config=TINY, settings=_settings(6), progress=False
    )
    half = train(
        [seq_dir], tmp_path / "half.pt", model_config=TINY, settings=_settings(3), progress=False
    )
    assert read_checkpoint(tmp_path / "half.pt")["train"]["step"] == 3
    rest = train(
        [seq_dir],
        tmp_path / "half.pt",
        settings=_settings(6),
        progress=False,
        resume=tmp_path / "half.pt",
    )
    assert rest.step == 6 and len(rest.losses) == 3
    assert half.losses + rest.losses == full.losses
    a = read_checkpoint(tmp_path / "full.pt")
    b = read_checkpoint(tmp_path / "half.pt")
    for k, v in a["state_dict"].items():
        assert torch.equal(v, b["state_dict"][k]), k
    assert b["meta"]["step"] == 6 and b["meta"]["resumed_from"] == str(tmp_path / "half.pt")
    assert len(b["meta"]["commands"]) == 2  # the first run's command line and the resume's


def test_periodic_checkpoints(seq_dir, tmp_path, monkeypatch):
    import rtdenoise.models.train as train_module

    saved = []
    real = train_module.save_checkpoint
    monkeypatch.setattr(
        train_module,
        "save_checkpoint",
        lambda path, model, meta, train=None: (
            saved.append(meta["step"]) or real(path, model, meta, train=train)
        ),
    )
    train(
        [seq_dir],
        tmp_path / "p.pt",
        model_config=TINY,
        settings=_settings(5, save_every=2, frames=2),
        progress=False,
    )
    assert saved == [2, 4, 5]


def test_cli_trains_validates_and_reports_errors(seq_dir, tmp_path):
    runner = CliRunner()
    out = tmp_path / "cli.pt"
    val_dir = write_sequence(tmp_path / "val", frames=3, size=30, seed=7)  # padded to 32
    args = [
        str(seq_dir),
        "-o",
        str(out),
        "--steps",
        "2",
        "--crop",
        "16",
        "--frames",
        "2",
        "--batch",
        "1",
        "--threads",
        "1",
        "--no-progress",
        "--val",
        str(val_dir),
        "--config",
        '{"widths": [8, 8, 8], "kernel_size": 3, "refine_width": 8}',
    ]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "validation: PSNR" in res.output and "wrote" in res.output
    model, meta = load_checkpoint(out)
    assert model.config()["widths"] == [8, 8, 8]
    val = meta["validation"]
    assert np.isfinite(val["psnr"]) and 10.0 < val["input_psnr"] < 20.0
    assert val["sequences"][0]["name"] == "val" and meta["val"] == [str(val_dir)]
    assert meta["command"].startswith("denoise-train")
    bad = runner.invoke(app, [str(tmp_path / "nowhere"), "-o", str(tmp_path / "x.pt")])
    assert bad.exit_code == 2 and "error:" in bad.output and "nowhere" in bad.output
    bad = runner.invoke(app, [*args[:3], "--config", "{not json"])
    assert bad.exit_code == 2 and "--config" in bad.output
    assert not (tmp_path / "x.pt").exists()


def test_cli_recipe_options_command_in_meta_and_eta_lines(seq_dir, tmp_path, monkeypatch):
    from rtdenoise.cli.train import Exposure, Loss, Schedule
    from rtdenoise.models.data import EXPOSURES
    from rtdenoise.models.losses import LOSSES
    from rtdenoise.models.schedule import SCHEDULES

    assert [e.value for e in Loss] == list(LOSSES)
    assert tuple(e.value for e in Schedule) == SCHEDULES
    assert tuple(e.value for e in Exposure) == EXPOSURES
    runner = CliRunner()
    out = tmp_path / "recipe.pt"
    args = [str(seq_dir), "-o", str(out), "--steps", "4", "--crop", "16", "--frames", "2",
            "--batch", "1", "--threads", "1", "--loss", "l1-ms-ssim", "--schedule", "onecycle",
            "--warmup", "0.25", "--rotations", "--permute-channels", "--exposure", "auto",
            "--log-every", "2", "--cache", str(tmp_path / "cache"), "--rel-l1-weight", "0.1",
            "--dark-edge-weight", "0.5", "--first-frame-weight", "2", "--config",
            '{"widths": [8, 8], "kernel_size": 3, "refine_width": 8}']  # fmt: skip
    monkeypatch.setattr("sys.argv", ["/some/bin/denoise-train", *args])
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    # not a terminal: plain progress lines with the ETA, one per --log-every steps
    lines = [ln for ln in res.output.splitlines() if ln.startswith("step ")]
    assert len(lines) == 2 and all("ETA" in ln and "lr" in ln for ln in lines), res.output
    _, meta = load_checkpoint(out)
    assert meta["argv"] == ["denoise-train", *args]
    assert meta["command"].startswith("denoise-train ") and "--loss l1-ms-ssim" in meta["command"]
    assert meta["commands"] == [meta["command"]]
    st = meta["settings"]
    assert (st["loss"], st["schedule"], st["warmup"]) == ("l1-ms-ssim", "onecycle", 0.25)
    assert st["rotations"] and st["permute"] and st["exposure"] == "auto"
    assert st["cache"] == str(tmp_path / "cache") and st["log_every"] == 2
    weights = (st["rel_l1_weight"], st["dark_edge_weight"], st["first_frame_weight"])
    assert weights == (0.1, 0.5, 2.0)
    assert [h[0] for h in meta["loss_history"]] == [2, 4]
    help_text = runner.invoke(app, ["--help"], env={"COLUMNS": "200"}).output
    for option in ("--loss", "--schedule", "--warmup", "--rotations", "--permute-channels",
                   "--exposure", "--cache", "--stop-at", "--log-every",
                   "--first-frame-weight"):  # fmt: skip
        assert option in help_text
    bad = runner.invoke(app, [*args[:3], "--loss", "l7"])
    assert bad.exit_code == 2


def test_cli_flushes_denormals_while_it_trains_and_gives_the_mode_back(
    seq_dir, tmp_path, monkeypatch
):
    """denoise-train flushes denormals during training (Intel cores pay a microcode assist per
    denormal: Isik21's steps ran 1.8x faster), --keep-denormals keeps IEEE underflow, and an
    in-process caller gets its own mode back, also when training fails."""
    import types

    import torch

    from rtdenoise.models import train as train_module

    seen = []

    def fake_train(*args, **kwargs):
        seen.append(torch.tensor([1e-39]).item())
        if len(seen) == 3:
            raise ValueError("no clips")
        return types.SimpleNamespace(losses=[0.5], checkpoint=tmp_path / "f.pt", step=1,
                                     seconds_per_step=0.1)  # fmt: skip

    monkeypatch.setattr(train_module, "train", fake_train)
    runner = CliRunner()
    args = [str(seq_dir), "-o", str(tmp_path / "f.pt"), "--steps", "1", "--no-progress"]
    assert runner.invoke(app, args).exit_code == 0
    assert seen[-1] == 0.0  # flushed while training
    assert torch.tensor([1e-39]).item() > 0.0  # and given back
    assert runner.invoke(app, [*args, "--keep-denormals"]).exit_code == 0
    assert seen[-1] > 0.0
    assert runner.invoke(app, args).exit_code != 0  # training failed: the mode given back too
    assert seen[-1] == 0.0 and torch.tensor([1e-39]).item() > 0.0


def test_non_finite_loss_stops_training(seq_dir, tmp_path, monkeypatch):
    from rtdenoise.models.registry import family_class

    nan = torch.tensor(float("nan"))
    monkeypatch.setattr(family_class("afn"), "loss", lambda self, *a, **k: nan)
    with pytest.raises(RuntimeError, match="non-finite training loss at step 1"):
        train(
            [seq_dir], tmp_path / "n.pt", model_config=TINY, settings=_settings(2), progress=False
        )
    assert not (tmp_path / "n.pt").exists()


def test_init_from_starts_a_new_run_from_a_checkpoints_weights(seq_dir, tmp_path):
    """Fine-tuning: the weights come from the checkpoint, the config from it updated by
    --config where the shapes stay; another family or changed shapes are refused by name."""
    from rtdenoise.models.checkpoint import CheckpointError

    source = train([seq_dir], tmp_path / "a.pt", model_config=TINY, settings=_settings(2),
                   command="stage 1")  # fmt: skip
    src_model, _ = load_checkpoint(source.checkpoint)
    tuned = train(
        [seq_dir], tmp_path / "b.pt", init_from=source.checkpoint,
        model_config={"reprojection": "per_tap"}, settings=_settings(1, lr=0.0), command="stage 2",
    )  # fmt: skip
    model, meta = load_checkpoint(tuned.checkpoint)
    assert model.config() == {**src_model.config(), "reprojection": "per_tap"}
    weights = model.state_dict()
    for name, w in src_model.state_dict().items():
        assert torch.equal(weights[name], w), name  # lr 0: the source's weights
    assert meta["initialised_from"] == str(source.checkpoint) and meta["step"] == 1
    # every stage's command line, the source's first: the meta says how to remake the weights
    assert meta["command"] == "stage 2" and meta["commands"] == ["stage 1", "stage 2"]
    with pytest.raises(CheckpointError, match=r"a\.pt: the config changes the weights .*"):
        train([seq_dir], tmp_path / "c.pt", init_from=source.checkpoint,
              model_config={"widths": [8, 16]}, settings=_settings(1))  # fmt: skip
    with pytest.raises(CheckpointError, match="family 'afn' differs from --family 'wskp'"):
        train([seq_dir], tmp_path / "c.pt", family="wskp", init_from=source.checkpoint,
              settings=_settings(1))  # fmt: skip
    assert not (tmp_path / "c.pt").exists()


def test_cli_init_from_a_demo_with_isik21_deployment_relu(seq_dir, tmp_path):
    """Isik21 §5.4's deployment step: demo:affinity's weights with ReLU for leaky ReLU."""
    runner = CliRunner()
    out = tmp_path / "relu.pt"
    args = [str(seq_dir), "-o", str(out), "--family", "affinity", "--steps", "1",
            "--crop", "16", "--frames", "2", "--batch", "1", "--lr", "0", "--threads", "1",
            "--no-progress", "--init-from", "demo:affinity",
            "--config", '{"leaky_slope": 0}']  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    demo, _ = load_checkpoint(demo_model("affinity", ".pt"))
    model, meta = load_checkpoint(out)
    assert model.config() == {**demo.config(), "leaky_slope": 0}
    assert all(torch.equal(model.state_dict()[k], v) for k, v in demo.state_dict().items())
    assert meta["initialised_from"].endswith("affinity.pt")
    both = runner.invoke(app, [*args, "--resume", str(out)])
    assert both.exit_code == 2 and "--init-from" in both.output
