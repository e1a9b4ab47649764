"""Batches drawn by worker processes: batch k from its own random stream (seed, k).

`ClipSampler.sample()` draws batch after batch from one stream in the training process, which
a checkpoint saves and a resume restores (`--workers 0`, the default and what the demos used).
At 256 px crops, batch 16 and 8 frames a batch is 16x the pixels of the 128 px, batch 4 one
that takes 56 ms in memory and 100 ms memory-mapped on this CPU (docs/architecture.md,
"Training"), so on a GPU one process cannot feed the model. With `workers >= 1`, batch k is
`sampler.sample(np.random.default_rng([seed, k]))`, computed ahead by a torch DataLoader's
worker processes (which inherit the sequences by fork: memory-mapped or copy-on-write, never
copied): it depends only on the seed and k, so the number of workers does not change a run and
a resume at step k needs no sampler state.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch

from .data import Batch, ClipSampler


def step_rng(seed: int, step: int) -> np.random.Generator:
    """The random stream of batch `step` (0-based) of a run seeded `seed`."""
    return np.random.default_rng([int(seed) % 2**63, int(step)])


class _StepBatches(torch.utils.data.Dataset):
    def __init__(self, sampler: ClipSampler, seed: int, start: int, stop: int) -> None:
        self.sampler, self.seed, self.start, self.stop = sampler, seed, start, stop

    def __len__(self) -> int:
        return self.stop - self.start

    def __getitem__(self, i: int) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        batch = self.sampler.sample(step_rng(self.seed, self.start + i))
        return batch.buffers, batch.reference


def step_batches(
    sampler: ClipSampler, seed: int, start: int, stop: int, workers: int
) -> Iterator[Batch]:
    """Batches `start` .. `stop - 1` in order, drawn by `workers` processes (2 batches ahead
    each); 0 workers draws them in this process (the same batches)."""
    data = _StepBatches(sampler, seed, start, stop)
    if workers <= 0:
        for i in range(len(data)):
            yield Batch(*data[i])
        return
    loader = torch.utils.data.DataLoader(
        data,
        batch_size=None,
        shuffle=False,
        num_workers=int(workers),
        prefetch_factor=2,
        persistent_workers=False,
    )
    for buffers, reference in loader:
        yield Batch(buffers, reference)


__all__ = ["step_batches", "step_rng"]
