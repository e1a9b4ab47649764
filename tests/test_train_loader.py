"""Batches from worker processes (models/loader.py): batch k depends only on (seed, k)."""

from __future__ import annotations

import numpy as np
import torch
from train_data import INPUTS, TINY, write_sequence

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.data import ClipSampler, load_sequence
from rtdenoise.models.loader import step_batches, step_rng
from rtdenoise.models.train import TrainSettings, train


def test_worker_batches_equal_the_in_process_ones(tmp_path):
    seq = load_sequence(write_sequence(tmp_path / "s", frames=4, size=24), INPUTS)
    sampler = ClipSampler([seq], np.random.default_rng(0), frames=2, crop=16, batch=2,
                          rotations=True, permute=True)  # fmt: skip
    here = list(step_batches(sampler, 7, 3, 7, workers=0))
    there = list(step_batches(sampler, 7, 3, 7, workers=2))
    assert len(here) == len(there) == 4
    for a, b in zip(here, there, strict=True):
        assert torch.equal(a.reference, b.reference)
        for k in a.buffers:
            assert torch.equal(a.buffers[k], b.buffers[k]), k
    direct = sampler.sample(step_rng(7, 5))
    assert torch.equal(direct.reference, here[2].reference)
    assert not torch.equal(here[0].reference, here[1].reference)


def test_workers_run_resumes_exactly(tmp_path):
    seq_dir = write_sequence(tmp_path / "s", frames=4, size=24)
    s = dict(steps=4, crop=16, frames=2, batch=1, seed=2, save_every=0, threads=1)
    quiet = dict(progress=False, log=lambda _: None)
    one = train([seq_dir], tmp_path / "one.pt", model_config=TINY,
                settings=TrainSettings(**s, workers=1), **quiet)  # fmt: skip
    half = tmp_path / "half.pt"
    first = train([seq_dir], half, model_config=TINY,
                  settings=TrainSettings(**s, workers=2, stop_at=2), **quiet)  # fmt: skip
    rest = train([seq_dir], half, settings=TrainSettings(**s, workers=2), resume=half, **quiet)
    assert first.losses + rest.losses == one.losses
    a, b = read_checkpoint(tmp_path / "one.pt"), read_checkpoint(half)
    for k, v in a["state_dict"].items():
        assert torch.equal(v, b["state_dict"][k]), k
