"""Learning-rate schedules (models/schedule.py): their shape, and a scheduled run of N steps
equals N/2 steps + a resume for N/2 (scheduler state in the checkpoint), bit for bit."""

from __future__ import annotations

import pytest
import torch
from train_data import TINY, write_sequence

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.schedule import build_scheduler, cosine_factor
from rtdenoise.models.train import TrainSettings, train


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return write_sequence(tmp_path_factory.mktemp("sched") / "seq", frames=4, size=24)


def _settings(steps: int, **kw) -> TrainSettings:
    base = dict(steps=steps, crop=16, frames=2, batch=1, lr=1e-2, seed=5, save_every=0,
                threads=1, log_every=1)  # fmt: skip
    return TrainSettings(**{**base, **kw})


def _lrs(kind: str, steps: int, warmup: float = 0.25, lr: float = 1e-3) -> list[float]:
    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=lr)
    sched = build_scheduler(opt, kind, steps, warmup)
    out = []
    for _ in range(steps):
        out.append(opt.param_groups[0]["lr"])
        opt.step()
        if sched is not None:
            sched.step()
    return out


@pytest.mark.parametrize("kind", ["onecycle", "cosine"])
def test_schedules_warm_up_then_decay(kind):
    lr = _lrs(kind, 40)
    peak = max(range(40), key=lambda i: lr[i])
    assert lr[0] == pytest.approx(1e-3 / 25, rel=1e-6)
    assert lr[peak] == pytest.approx(1e-3, rel=1e-3) and 8 <= peak <= 10
    assert all(a <= b for a, b in zip(lr[:peak], lr[1 : peak + 1], strict=True))
    assert all(a >= b for a, b in zip(lr[peak:-1], lr[peak + 1 :], strict=True))
    assert lr[-1] == pytest.approx(1e-3 / 25 / 1e4, rel=1e-3)
    assert _lrs("constant", 5) == [1e-3] * 5
    assert cosine_factor(0, 40, 0.25) == pytest.approx(1 / 25)


@pytest.mark.parametrize("kind", ["onecycle", "cosine"])
def test_scheduled_resume_equals_uninterrupted_run(seq_dir, tmp_path, kind):
    s = dict(schedule=kind, warmup=0.3)
    quiet = dict(progress=False, log=lambda _: None)
    full = train([seq_dir], tmp_path / "full.pt", model_config=TINY, settings=_settings(6, **s),
                 **quiet)  # fmt: skip
    # the 6-step schedule stopped after step 3 (a long run in pieces), then resumed
    half = tmp_path / "half.pt"
    first = train([seq_dir], half, model_config=TINY, settings=_settings(6, stop_at=3, **s),
                  **quiet)  # fmt: skip
    assert first.step == 3 and read_checkpoint(half)["train"]["scheduler"]["last_epoch"] == 3
    rest = train([seq_dir], half, settings=_settings(6, **s), resume=half, **quiet)
    assert first.losses + rest.losses == full.losses
    a, b = read_checkpoint(tmp_path / "full.pt"), read_checkpoint(half)
    for k, v in a["state_dict"].items():
        assert torch.equal(v, b["state_dict"][k]), k
    assert a["meta"]["lr_last"] == b["meta"]["lr_last"]
    assert a["train"]["scheduler"]["last_epoch"] == b["train"]["scheduler"]["last_epoch"] == 6
    history = b["meta"]["loss_history"]  # [step, loss, lr] per step (log_every = 1)
    assert history == a["meta"]["loss_history"]
    assert [h[1] for h in history] == pytest.approx(full.losses)
    # the learning rate did follow the schedule (from lr / 25 up, then down)
    lrs = [h[2] for h in history]
    assert lrs == pytest.approx(_lrs(kind, 6, 0.3, lr=1e-2))
    assert lrs[0] == pytest.approx(1e-2 / 25) and lrs[0] < lrs[1] and lrs[-1] < lrs[-2]
    # another schedule cannot continue it
    with pytest.raises(ValueError, match="schedule"):
        train([seq_dir], tmp_path / "x.pt", settings=_settings(8, **s), resume=half, **quiet)


def test_the_scheduler_matters_for_resume(seq_dir, tmp_path, monkeypatch):
    """Without its state a resumed onecycle run restarts the warm-up: the losses differ, so the
    test above would catch a checkpoint that dropped it."""
    s = dict(schedule="onecycle", warmup=0.3)
    quiet = dict(progress=False, log=lambda _: None)
    full = train([seq_dir], tmp_path / "f.pt", model_config=TINY, settings=_settings(6, **s),
                 **quiet)  # fmt: skip
    half = tmp_path / "h.pt"
    train([seq_dir], half, model_config=TINY, settings=_settings(6, stop_at=3, **s), **quiet)
    monkeypatch.setattr(torch.optim.lr_scheduler.OneCycleLR, "load_state_dict", lambda *a: None)
    rest = train([seq_dir], half, settings=_settings(6, **s), resume=half, **quiet)
    assert rest.losses != full.losses[3:]


def test_progress_lines_and_clock():
    from rtdenoise.models.progress import TrainProgress, clock

    assert (clock(59.4), clock(61), clock(3 * 3600 + 62)) == ("0:59", "1:01", "3:01:02")
    lines = []
    with TrainProgress(10, 2, bar=False, log=lines.append) as p:
        p.update(3, 0.5, 1e-3)
        p.window(4, 0.25, 1e-3)
    (line,) = lines
    assert line.startswith("step 4/10: loss 0.2500, lr 1.0e-03, ") and "ETA " in line
