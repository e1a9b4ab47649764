"""Supervised training of a denoiser on EXR sequences (Lee24 IV-B).

Each step draws a batch of clips (random crop, flips, quarter turns, colour permutation,
exposure and brightness, models.data / models.augment), unrolls the model over the clip with
its state carried (reset = 1 and zero state on the clip's first frame), and minimises the
chosen loss (models.losses: the family's own, by default SMAPE (Lee24 eq. (5)) + w * temporal
SMAPE (Isik21 eq. (12)); or Open Image Denoise's L1 + MS-SSIM on a perceptual transfer curve)
with Adam under a learning-rate schedule (models.schedule). Checkpoints (models.checkpoint) are
written atomically every `save_every` steps and at the end; they hold the optimizer and
scheduler states, the step and every RNG state, so that a resumed run continues exactly as an
uninterrupted one would, and the meta records the command line and every setting.
"""

from __future__ import annotations

import os
import random
import shlex
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.sequences.layouts import get_layout
from rtdenoise.runtime.sequences.metrics import psnr
from rtdenoise.runtime.sequences.samples import sample_features_of

from .base import DenoiserModel
from .checkpoint import CheckpointError, load_checkpoint, load_training_state, save_checkpoint
from .data import ClipSampler, SequenceData, load_sequences, oversampled, training_folders
from .device import torch_device
from .frame_loop import FrameLoop, unroll
from .loader import step_batches
from .losses import training_loss
from .progress import TrainProgress
from .registry import build_model
from .schedule import build_scheduler, check_resumable, schedule_settings


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
    log_every: int = 50  # window of the loss history kept in meta ([step, mean loss, lr])
    threads: int | None = 2  # torch intra-op threads (None: leave torch's default)
    sample_counts: tuple[int, ...] = ()  # per-sample models: S per batch drawn from these
    device: str = "cpu"  # torch device of the model and batches: cpu, cuda, cuda:N
    loss: str = "paper"  # models.losses.LOSSES: paper (the family's), smape, l1-ms-ssim
    relmse_weight: float = 0.0  # + this x relMSE of the outputs (models.losses.relmse)
    rel_l1_weight: float = 0.0  # + this x relative L1 of the outputs (models.losses.relative_l1)
    dark_edge_weight: float = 0.0  # + this x models.losses.dark_edge_l1 of the outputs
    first_frame_weight: float = 0.0  # + this x the loss of each clip's first frame (no history)
    rotations: bool = False  # random quarter turns (models.augment)
    permute: bool = False  # random permutation of the colour channels (models.augment)
    exposure: str = "none"  # none or auto (models.data)
    schedule: str = "constant"  # models.schedule.SCHEDULES: constant, onecycle, cosine, step
    warmup: float = 0.15  # warm-up fraction of the steps of onecycle / cosine
    cache: str | None = None  # folder of the memory-mapped sequence cache (models.cache)
    layout: str = "canonical"  # the sequences' layout: a preset name or a layout file (.toml)
    stop_at: int | None = None  # end this call after this step (the schedule spans `steps`)
    workers: int = 0  # >= 1: batch k from stream (seed, k), drawn by worker processes
    recipe: str = "default"  # models.recipes: the settings this run started from
    # meta.json kind -> N: sequences of that kind are drawn N times as often (models.data)
    oversample: dict[str, int] = field(default_factory=dict)


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
        frames = (seq.frame(i) for i in range(seq.frames))
        outputs = [out[0].cpu().numpy() for out in loop.run(frames)]
        scores = [
            psnr(out, np.asarray(ref, np.float32))
            for out, ref in zip(outputs, seq.reference, strict=True)
        ]
        inputs = [
            psnr(np.asarray(c, np.float32), np.asarray(ref, np.float32))
            for c, ref in zip(seq.buffers["color"], seq.reference, strict=True)
        ]
        per_seq.append(
            {"name": seq.name, "psnr": float(np.mean(scores)), "input_psnr": float(np.mean(inputs))}
        )
    model.train(was_training)
    return {
        "psnr": float(np.mean([s["psnr"] for s in per_seq])),
        "input_psnr": float(np.mean([s["input_psnr"] for s in per_seq])),
        "sequences": per_seq,
    }


def _settings_meta(s: TrainSettings) -> dict:
    """The settings as JSON-able plain data (tuples as lists)."""
    return {
        **asdict(s),
        "brightness": list(s.brightness),
        "sample_counts": list(s.sample_counts),
    }


def _check_family(model: DenoiserModel, family: str, path: str | os.PathLike) -> None:
    if model.family != family:
        raise CheckpointError(
            f"{path}: checkpoint family {model.family!r} differs from --family {family!r}"
        )


def initial_weights(
    path: str | os.PathLike, family: str, model_config: dict | None = None
) -> tuple[DenoiserModel, dict]:
    """A `family` model with the weights of checkpoint `path` and its config updated by
    `model_config`, and that checkpoint's meta: the start of a fine-tuning run. A weight whose
    input channels (dim 1) the config grows keeps its channels first and starts the new ones at
    zero, so the model computes what the checkpoint did: families append an input an option
    adds (nbg's and afn's `history_input`) after the others. Refuses another family or any
    other change of a weight's name or shape, naming them."""
    source, meta = load_checkpoint(path)
    _check_family(source, family, path)
    model = build_model(family, {**source.config(), **(model_config or {})})
    theirs, ours = source.state_dict(), model.state_dict()
    grown = {k for k in theirs.keys() & ours.keys() if _grows_inputs(theirs[k], ours[k])}
    changed = sorted(
        k for k in theirs.keys() | ours.keys()
        if k not in grown
        and (k not in theirs or k not in ours or theirs[k].shape != ours[k].shape)
    )  # fmt: skip
    if changed:
        raise CheckpointError(
            f"{path}: the config changes the weights {', '.join(changed[:6])}"
            f"{' ...' if len(changed) > 6 else ''}; fine-tuning keeps every weight's shape"
            " (or grows its input channels)"
        )
    for k in grown:
        weight = torch.zeros_like(ours[k])
        weight[:, : theirs[k].shape[1]] = theirs[k]
        theirs[k] = weight
    model.load_state_dict(theirs)
    return model, meta


def _grows_inputs(old: torch.Tensor, new: torch.Tensor) -> bool:
    """`new` is `old` with more input channels (dim 1) of a conv or linear weight."""
    return (
        old.ndim == new.ndim >= 2
        and new.shape[1] > old.shape[1]
        and old.shape[:1] + old.shape[2:] == new.shape[:1] + new.shape[2:]
    )


def commands_of(meta: dict) -> list[str]:
    """The command lines that made a checkpoint, oldest first (older ones record one)."""
    return list(meta.get("commands", [meta["command"]] if "command" in meta else []))


def train(
    data_dirs: Sequence[str | os.PathLike],
    output: str | os.PathLike,
    *,
    family: str = "afn",
    model_config: dict | None = None,
    settings: TrainSettings | None = None,
    resume: str | os.PathLike | None = None,
    init_from: str | os.PathLike | None = None,
    val_dirs: Sequence[str | os.PathLike] = (),
    progress: bool = True,
    log: Callable[[str], None] = print,
    command: str | None = None,
) -> TrainResult:
    """Train (or resume training) a `family` model on sequence folders; write `output`.

    With `resume`, the model, optimizer, scheduler, step and RNG states come from that
    checkpoint (its family / config win over `family` / `model_config`) and training continues
    up to `settings.steps` (or `settings.stop_at`: a long schedule run in pieces). With
    `init_from` (fine-tuning), a new run starts from that checkpoint's weights, its config
    updated by `model_config` (e.g. Isik21 §5.4: `{"leaky_slope": 0}`). `progress`:
    a rich bar where stderr is a terminal, else (and without it) a line per logging window with
    the ETA. `command`: the command line recorded in the meta (default: this process's argv).
    Returns the per-step losses of this call and validation metrics.
    """
    s = settings or TrainSettings()
    device = torch_device(s.device)
    if s.threads:
        torch.set_num_threads(int(s.threads))
    output = Path(output)
    command = command if command is not None else shlex.join(sys.argv)
    rng = seed_everything(s.seed)
    train_state: dict | None = None
    meta_in: dict = {}
    earlier_commands: list[str] = []  # what made the weights this run starts from
    if resume is not None:
        model, meta_in, train_state = load_training_state(resume)
        _check_family(model, family, resume)
        earlier_commands = commands_of(meta_in)
    elif init_from is not None:
        model, source_meta = initial_weights(init_from, family, model_config)
        earlier_commands = commands_of(source_meta)
    else:
        model = build_model(family, model_config)
    model.to(device).train()
    loss_fn = training_loss(
        s.loss,
        model,
        s.relmse_weight,
        s.rel_l1_weight,
        s.dark_edge_weight,
        s.first_frame_weight,
    )
    schedule = schedule_settings(s.schedule, s.steps, s.warmup)
    if train_state is not None:
        check_resumable(train_state.get("schedule"), schedule, str(resume))
    features = sample_features_of(model.config()) if SAMPLES in model.inputs else None
    layout = get_layout(s.layout)  # a bad name or file fails before any sequence is read
    folders, incomplete = training_folders(data_dirs)
    if incomplete:
        log(f"data: left out {len(incomplete)} incomplete sequence(s) (no meta.json yet)")
    drawn = oversampled(folders, s.oversample)
    sequences = load_sequences(drawn, model.inputs, features, cache=s.cache, layout=layout)
    val_buffers = tuple(dict.fromkeys((*model.inputs, "color")))  # + the noisy input's PSNR
    val_sequences = (
        load_sequences(val_dirs, val_buffers, features, layout=layout) if val_dirs else []
    )
    where = f"memory-mapped from {s.cache}" if s.cache else "in memory"
    extra = f" (+{len(drawn) - len(folders)} repeats: oversampled)" if s.oversample else ""
    log(
        f"data: {len(folders)} sequence(s){extra}, "
        f"{sum(q.nbytes for q in {id(q): q for q in sequences}.values()) / 2**20:.0f} MiB "
        f"{where}"
    )
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
        rotations=s.rotations,
        permute=s.permute,
        exposure=s.exposure,
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=s.lr)
    scheduler = build_scheduler(optimizer, s.schedule, s.steps, s.warmup)
    step = 0
    history: list[list[float]] = list(meta_in.get("loss_history", []))
    commands = [*earlier_commands, command]
    if train_state is not None:
        optimizer.load_state_dict(train_state["optimizer"])
        if scheduler is None:  # a constant rate: this run's --lr (it may change on resume)
            for group in optimizer.param_groups:
                group["lr"] = s.lr
        else:
            scheduler.load_state_dict(train_state["scheduler"])
        step = int(train_state["step"])
        restore_rng_state(train_state["rng"], rng)

    def lr_now() -> float:
        return float(optimizer.param_groups[0]["lr"])

    def checkpoint(validation: dict | None = None) -> None:
        meta = {
            "step": step,
            "loss_history": history,
            "loss_last": losses[-1] if losses else meta_in.get("loss_last"),
            "lr_last": lr_now(),
            "data": [str(Path(d)) for d in data_dirs],
            "sequences": [str(f) for f in folders],
            "val": [str(Path(d)) for d in val_dirs],
            "seed": s.seed,
            "settings": _settings_meta(s),
            "command": command,
            "argv": shlex.split(command),
            "commands": commands,
            "torch": str(torch.__version__),
            "resumed_from": str(resume) if resume is not None else meta_in.get("resumed_from"),
            "initialised_from": (
                str(init_from) if init_from is not None else meta_in.get("initialised_from")
            ),
        }
        if validation is not None:
            meta["validation"] = validation
        train_blob = {
            "optimizer": _to_cpu(optimizer.state_dict()),
            "scheduler": scheduler.state_dict() if scheduler is not None else None,
            "schedule": schedule,
            "step": step,
            "rng": rng_state(rng),
        }
        save_checkpoint(output, model, meta, train=train_blob)

    losses: list[float] = []
    window: list[float] = []
    start_step = step
    t0 = time.perf_counter()
    bar = progress and _stderr_is_terminal()
    last = s.steps if s.stop_at is None else max(step, min(s.steps, int(s.stop_at)))
    if s.workers:  # batch k depends on (seed, k) only: no sampler state to resume
        batches = step_batches(sampler, s.seed, step, last, s.workers)
    else:  # one stream in this process, saved in the checkpoint
        batches = (sampler.sample() for _ in range(step, last))
    with TrainProgress(last, step, bar=bar, log=log) as shown:
        for batch in batches:
            buffers = {k: v.to(device, non_blocking=True) for k, v in batch.buffers.items()}
            outputs = unroll(model, buffers)
            loss = loss_fn(outputs, batch.reference.to(device), s.temporal_weight)
            if not torch.isfinite(loss):
                raise RuntimeError(
                    f"non-finite training loss at step {step + 1}; weights not updated "
                    f"(last checkpoint: {output if output.exists() else 'none'})"
                )
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            lr = lr_now()
            optimizer.step()
            if scheduler is not None:
                scheduler.step()
            step += 1
            value = float(loss.detach())
            losses.append(value)
            window.append(value)
            shown.update(step, value, lr)
            if step % max(1, s.log_every) == 0 or step == last:
                history.append([step, float(np.mean(window)), lr])
                window = []
                shown.window(step, history[-1][1], lr)
            if s.save_every and step % s.save_every == 0 and step < last:
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


def _stderr_is_terminal() -> bool:
    """Whether a rich bar would show (rich draws on stderr here; a log or pipe gets lines)."""
    return bool(getattr(sys.stderr, "isatty", None) and sys.stderr.isatty())
