"""Training recipes (models/recipes.py, `denoise-train --recipe`): each paper's settings
reach the run, an explicit option beats the recipe, the checkpoint meta records it; the
`step` schedule (Isik21) and Fan21's input clip and SMAPE eps."""

from __future__ import annotations

import pytest
import torch
from train_data import write_sequence
from typer.testing import CliRunner

from rtdenoise.cli.train import app
from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.models.losses import sequence_loss
from rtdenoise.models.recipes import RECIPE_NAMES, recipe_settings
from rtdenoise.models.registry import build_model
from rtdenoise.models.schedule import build_scheduler, step_factor
from rtdenoise.models.train import TrainSettings

WSKP_TINY = '{"width": 6, "layers": 3}'


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("recipes") / "seq", frames=3, size=24)


def test_every_recipe_names_real_settings():
    fields = set(TrainSettings.__dataclass_fields__)
    for name in RECIPE_NAMES:
        for family in ("affinity", "afn", "wskp", "nbg"):
            values, config = recipe_settings(name, family)
            assert set(values) <= fields, (name, family)
            build_model(family, config)  # the overrides are valid config fields
    assert recipe_settings("default", "afn") == ({}, {})
    assert recipe_settings("paper", "affinity")[0]["lr"] == 1e-4  # Isik21 s.5
    assert recipe_settings("paper", "nbg")[0]["batch"] == 20  # Meng20 s.5
    assert recipe_settings("paper", "afn")[0]["temporal_weight"] == 0.0  # Lee24: SMAPE alone
    with pytest.raises(ValueError, match="online"):
        recipe_settings("paper", "crossreg")
    with pytest.raises(ValueError, match="unknown recipe"):
        recipe_settings("mine", "afn")


def test_step_schedule_decays_by_a_quarter_every_fifth():
    assert [step_factor(s, 100) for s in (0, 19, 20, 39, 40, 99)] == [
        1.0, 1.0, 0.75, 0.75, 0.75**2, 0.75**4,
    ]  # fmt: skip
    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-4)
    sched = build_scheduler(opt, "step", 10)
    lrs = []
    for _ in range(10):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs == pytest.approx([1e-4 * 0.75 ** (i // 2) for i in range(10)])


def test_fan21_input_clip_and_smape_eps():
    torch.manual_seed(0)
    n, h, w = 1, 16, 16
    buffers = {
        "color": torch.rand(n, 3, h, w) * 8.0,  # highlights far above 1
        "albedo": torch.rand(n, 3, h, w) * 0.8 + 0.1,
        "normal": torch.nn.functional.normalize(torch.randn(n, 3, h, w), dim=1),
        "depth": torch.rand(n, 1, h, w) + 1.0,
        "motion": torch.zeros(n, 2, h, w),
    }
    outputs = {}
    for clip in (False, True):
        torch.manual_seed(1)
        model = build_model("wskp", {"width": 6, "layers": 3, "input_clip": clip}).eval()
        state = model.initial_state(n, h, w)
        with torch.no_grad():
            outputs[clip], _ = model(buffers, state, torch.tensor(1.0))
    assert not torch.allclose(outputs[False], outputs[True])  # the clip changes the input
    # with colours all below 1 the clip is the identity
    dim = dict(buffers, color=buffers["color"] / 100.0)
    same = []
    for clip in (False, True):
        torch.manual_seed(1)
        model = build_model("wskp", {"width": 6, "layers": 3, "input_clip": clip}).eval()
        with torch.no_grad():
            same.append(model(dim, model.initial_state(n, h, w), torch.tensor(1.0))[0])
    torch.testing.assert_close(same[0], same[1], rtol=0, atol=0)
    out, ref = torch.rand(1, 2, 3, 4, 4), torch.rand(1, 2, 3, 4, 4)
    model = build_model("wskp", {"width": 6, "layers": 3, "smape_eps": 1e-2})
    assert model.loss(out, ref, 0.0) == sequence_loss(out, ref, 0.0, eps=1e-2)
    assert model.loss(out, ref, 0.0) != sequence_loss(out, ref, 0.0)


def test_cli_paper_recipe_reaches_the_run_and_explicit_options_win(seq_dir, tmp_path):
    runner = CliRunner()
    out = tmp_path / "wskp.pt"
    args = [str(seq_dir), "-o", str(out), "--family", "wskp", "--recipe", "paper",
            "--steps", "2", "--crop", "16", "--frames", "2", "--batch", "1", "--threads", "1",
            "--config", WSKP_TINY, "--no-progress"]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    model, meta = load_checkpoint(out)
    st = meta["settings"]
    assert st["recipe"] == "paper"
    # the recipe's (Fan21 official code) ...
    assert st["rotations"] and st["flips"] and st["temporal_weight"] == 0.0
    assert tuple(st["brightness"]) == (1.0, 1.0)
    assert model.cfg.input_clip and model.cfg.smape_eps == 1e-2
    # ... and the command line's, which beat the recipe's batch 64 and crop 128
    assert (st["batch"], st["crop"]) == (1, 16)
    assert (model.cfg.width, model.cfg.layers) == (6, 3)
    bad = runner.invoke(app, [*args[:3], "--family", "crossreg", "--recipe", "paper"])
    assert bad.exit_code != 0 and "online" in bad.output
