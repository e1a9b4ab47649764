"""Supervised training of a denoiser on EXR sequences (Lee24 IV-B).

Each step draws a batch of clips (random crop + flips + brightness, models.data), unrolls
the model over the clip with its state carried (reset = 1 and zero state on the clip's
first frame), and minimises SMAPE (Lee24 eq. (5)) + w * temporal SMAPE (Isik21 eq. (12))
with Adam. Checkpoints (models.checkpoint) are written atomically every `save_every` steps
and at the end; they hold the optimizer state, the step and every RNG state, so that a
resumed run continues exactly as an uninterrupted one would.
"""

from __future__ import annotations

import os
import random
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.sequences.metrics import psnr
from rtdenoise.runtime.sequences.samples import sample_features_of

from .base import DenoiserModel
from .checkpoint import CheckpointError, load_training_state, save_checkpoint
from .data import ClipSampler, SequenceData, load_sequences
from .device import torch_device
from .frame_loop import FrameLoop, unroll
from .registry import build_model


@dataclass
class TrainSettings:
    """Hyper-parameters of a run (stored in the checkpoint meta)."""

    steps: int = 1000  # total optimisation steps (a resumed run continues up to this)
    crop: int = 128
    frames: int = 8
    batch: int = 4
    lr: float = 1e-3
    seed: int = 0
    temporal_weight: float = 0.25
    brightness: tuple[float, float] = (0.8, 1.2)  # (1, 1) disables it
    flips: bool = True
    save_every: int = 500  # steps between checkpoints (0: only at the end)
    log_every: int = 50  # window of the loss history kept in meta
    threads: int | None = 2  # torch intra-op threads (None: leave torch's default)
    sample_counts: tuple[int, ...] = ()  # per-sample models: S per batch drawn from these
    device: str = "cpu"  # torch device of the model and batches: cpu, cuda, cuda:N


@dataclass
class TrainResult:
    """What a run did: per-step losses of this process, final step, validation metrics."""

    checkpoint: Path
    step: int
    losses: list[float] = field(default_factory=list)
    validation: dict | None = None
    seconds_per_step: float = 0.0


def _to_cpu(obj):
    """`obj` (nested dicts / lists of tensors, an optimizer state) with every tensor on the CPU,
    so a checkpoint written on a GPU loads anywhere."""
    if isinstance(obj, torch.Tensor):
        return obj.cpu()
    if isinstance(obj, dict):
        return {k: _to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return type(obj)(_to_cpu(v) for v in obj)
    return obj


def seed_everything(seed: int) -> np.random.Generator:
    """Seed python `random`, numpy's global RNG and torch; return the sampling Generator.

    Training draws only from the returned Generator (clips) and torch (initialisation)."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return np.random.default_rng(seed)


def rng_state(rng: np.random.Generator) -> dict:
    """Every RNG state a resumed run needs (JSON-like + tensors: weights_only-loadable)."""
    return {
        "numpy_sampler": rng.bit_generator.state,
        "python": random.getstate(),
        "torch": torch.get_rng_state(),
    }


def restore_rng_state(state: dict, rng: np.random.Generator) -> None:
    rng.bit_generator.state = state["numpy_sampler"]
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    torch.set_rng_state(state["torch"])


@torch.no_grad()
def evaluate(model: DenoiserModel, sequences: Sequence[SequenceData]) -> dict:
    """Mean tau-PSNR (Isik21 eq. (14), runtime.metrics.psnr) of the model output and of the
    noisy input vs the reference, over every frame of every sequence, run at full size by the
    one frame loop (models.frame_loop: padded, state carried, cropped, as the executor does)."""
    was_training = model.training
    model.eval()
    loop = FrameLoop(model)
    per_seq = []
    for seq in sequences:
        frames = ({n: a[i] for n, a in seq.buffers.items()} for i in range(seq.frames))
        outputs = [out[0].cpu().numpy() for out in loop.run(frames)]
        scores = [psnr(out, ref) for out, ref in zip(outputs, seq.reference, strict=True)]
        inputs = [psnr(c, ref) for c, ref in zip(seq.buffers["color"], seq.reference, strict=True)]
        per_seq.append(
            {"name": seq.name, "psnr": float(np.mean(scores)), "input_psnr": float(np.mean(inputs))}
        )
    model.train(was_training)
    return {
        "psnr": float(np.mean([s["psnr"] for s in per_seq])),
        "input_psnr": float(np.mean([s["input_psnr"] for s in per_seq])),
        "sequences": per_seq,
    }


class _Progress:
    """A rich progress bar showing the loss, or nothing."""

    def __init__(self, enabled: bool, total: int, start: int) -> None:
        self.bar = None
        if enabled:
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bar = Progress(
                TextColumn("[bold]train"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("loss {task.fields[loss]}"),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
            )
            self.task = self.bar.add_task("train", total=total, completed=start, loss="-")

    def __enter__(self) -> _Progress:
        if self.bar is not None:
            self.bar.start()
        return self

    def update(self, loss: float) -> None:
        if self.bar is not None:
            self.bar.update(self.task, advance=1, loss=f"{loss:.4f}")

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()


def train(
    data_dirs: Sequence[str | os.PathLike],
    output: str | os.PathLike,
    *,
    family: str = "afn",
    model_config: dict | None = None,
    settings: TrainSettings | None = None,
    resume: str | os.PathLike | None = None,
    val_dirs: Sequence[str | os.PathLike] = (),
    progress: bool = True,
    log: Callable[[str], None] = print,
    command: str | None = None,
) -> TrainResult:
    """Train (or resume training) a `family` model on sequence folders; write `output`.

    With `resume`, the model, optimizer, step and RNG states come from that checkpoint
    (its family / config win over `family` / `model_config`) and training continues up to
    `settings.steps`. Returns the per-step losses of this call and validation metrics.
    """
    s = settings or TrainSettings()
    device = torch_device(s.device)
    if s.threads:
        torch.set_num_threads(int(s.threads))
    output = Path(output)
    rng = seed_everything(s.seed)
    train_state: dict | None = None
    meta_in: dict = {}
    if resume is not None:
        model, meta_in, train_state = load_training_state(resume)
        if model.family != family:
            raise CheckpointError(
                f"{resume}: checkpoint family {model.family!r} differs from --family {family!r}"
            )
    else:
        model = build_model(family, model_config)
    model.to(device).train()
    features = sample_features_of(model.config()) if SAMPLES in model.inputs else None
    sequences = load_sequences(data_dirs, model.inputs, features)
    val_buffers = tuple(dict.fromkeys((*model.inputs, "color")))  # + the noisy input's PSNR
    val_sequences = load_sequences(val_dirs, val_buffers, features) if val_dirs else []
    sampler = ClipSampler(
        sequences,
        rng,
        frames=s.frames,
        crop=s.crop,
        batch=s.batch,
        multiple=model.pad_multiple,
        flips=s.flips,
        brightness=s.brightness,
        sample_features=features or (),
        sample_counts=s.sample_counts,
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=s.lr)
    step = 0
    history: list[list[float]] = list(meta_in.get("loss_history", []))
    if train_state is not None:
        optimizer.load_state_dict(train_state["optimizer"])
        for group in optimizer.param_groups:
            group["lr"] = s.lr
        step = int(train_state["step"])
        restore_rng_state(train_state["rng"], rng)

    def checkpoint(validation: dict | None = None) -> None:
        meta = {
            "step": step,
            "loss_history": history,
            "loss_last": losses[-1] if losses else meta_in.get("loss_last"),
            "data": [str(Path(d)) for d in data_dirs],
            "val": [str(Path(d)) for d in val_dirs],
            "seed": s.seed,
            "settings": {
                **asdict(s),
                "brightness": list(s.brightness),
                "sample_counts": list(s.sample_counts),
            },
            "command": command if command is not None else " ".join(sys.argv),
            "torch": str(torch.__version__),
            "resumed_from": str(resume) if resume is not None else meta_in.get("resumed_from"),
        }
        if validation is not None:
            meta["validation"] = validation
        train_blob = {
            "optimizer": _to_cpu(optimizer.state_dict()),
            "step": step,
            "rng": rng_state(rng),
        }
        save_checkpoint(output, model, meta, train=train_blob)

    losses: list[float] = []
    window: list[float] = []
    start_step = step
    t0 = time.perf_counter()
    with _Progress(progress, s.steps, step) as bar:
        while step < s.steps:
            batch = sampler.sample()
            buffers = {k: v.to(device, non_blocking=True) for k, v in batch.buffers.items()}
            outputs = unroll(model, buffers)
            loss = model.loss(outputs, batch.reference.to(device), s.temporal_weight)
            if not torch.isfinite(loss):
                raise RuntimeError(
                    f"non-finite training loss at step {step + 1}; weights not updated "
                    f"(last checkpoint: {output if output.exists() else 'none'})"
                )
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            step += 1
            value = float(loss.detach())
            losses.append(value)
            window.append(value)
            bar.update(value)
            if step % max(1, s.log_every) == 0 or step == s.steps:
                history.append([step, float(np.mean(window))])
                window = []
                if not progress:  # no bar (logs, CI): a line per logging window instead
                    log(f"step {step}/{s.steps}: loss {history[-1][1]:.4f}")
            if s.save_every and step % s.save_every == 0 and step < s.steps:
                checkpoint()
    seconds = (time.perf_counter() - t0) / max(1, step - start_step)
    validation = evaluate(model, val_sequences) if val_sequences else None
    if validation is not None:
        log(
            f"validation: PSNR {validation['psnr']:.2f} dB (noisy input "
            f"{validation['input_psnr']:.2f} dB) over {len(val_sequences)} sequence(s)"
        )
    checkpoint(validation)
    model.eval()
    return TrainResult(output, step, losses, validation, seconds)
