"""Learning-rate schedules of `denoise-train --schedule`, stepped once per optimisation step.

- `constant`: the Adam learning rate throughout (Lee24, Meng20; what the demos used).
- `onecycle`: torch's OneCycleLR (Smith & Topin 2019, "Super-convergence"), the schedule Open
  Image Denoise trains with: from lr / 25 up to lr over the first `warmup` fraction of the
  steps, then cosine annealing down to lr / 25 / 1e4 at the last step; momentum is not cycled.
- `cosine`: linear warm-up from lr / 25 to lr over the `warmup` fraction, then a cosine decay
  to lr / 25 / 1e4 at the last step (Loshchilov & Hutter 2017, SGDR, a single cycle).
- `step`: lr x 0.75 after every fifth of the steps (Isik21 s.5: x 0.75 every 150 of about 750
  epochs), no warm-up.

A schedule's state (torch's `state_dict`) goes into the training checkpoint and is restored on
resume, so a resumed run follows the same learning rates as an uninterrupted one; its settings
(kind, total steps, warm-up) must then be unchanged (`check_resumable`).
"""

from __future__ import annotations

import math

import torch

SCHEDULES = ("constant", "onecycle", "cosine", "step")
STEP_FACTOR = 0.75  # Isik21: x 0.75 ...
STEP_PERIODS = 5  # ... every 150 of 750 epochs
DIV_FACTOR = 25.0  # initial lr = lr / 25 (torch's OneCycleLR default)
FINAL_DIV_FACTOR = 1e4  # final lr = initial lr / 1e4


def cosine_factor(step: int, total: int, warmup: float) -> float:
    """lr multiplier of the `cosine` schedule before optimisation step `step` (0-based)."""
    start = 1.0 / DIV_FACTOR
    end = start / FINAL_DIV_FACTOR
    ramp = max(1, round(warmup * total))
    if step < ramp:
        return start + (1.0 - start) * step / ramp
    t = min(1.0, (step - ramp) / max(1, total - 1 - ramp))
    return end + (1.0 - end) * 0.5 * (1.0 + math.cos(math.pi * t))


def step_factor(step: int, total: int) -> float:
    """lr multiplier of the `step` schedule before optimisation step `step` (0-based)."""
    period = max(1, round(total / STEP_PERIODS))
    return STEP_FACTOR ** (step // period)


def build_scheduler(
    optimizer: torch.optim.Optimizer, kind: str, total_steps: int, warmup: float = 0.15
) -> torch.optim.lr_scheduler.LRScheduler | None:
    """The scheduler of `kind` over `total_steps` steps (None for `constant`)."""
    if kind not in SCHEDULES:
        raise ValueError(f"unknown schedule {kind!r}; choose one of {', '.join(SCHEDULES)}")
    if not 0.0 <= warmup < 1.0:
        raise ValueError(f"warm-up must be a fraction in [0, 1), got {warmup}")
    if kind == "constant":
        return None
    if kind == "onecycle":
        lr = [g["lr"] for g in optimizer.param_groups]
        # OneCycleLR divides by (warm-up steps - 1): at least 2 warm-up steps, 4 steps in all
        total = max(4, int(total_steps))
        return torch.optim.lr_scheduler.OneCycleLR(
            optimizer,
            max_lr=lr,
            total_steps=total,
            pct_start=max(warmup, 2.0 / total),
            anneal_strategy="cos",
            div_factor=DIV_FACTOR,
            final_div_factor=FINAL_DIV_FACTOR,
            cycle_momentum=False,
        )
    total = int(total_steps)
    if kind == "step":
        return torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: step_factor(step, total))
    return torch.optim.lr_scheduler.LambdaLR(
        optimizer, lambda step: cosine_factor(step, total, warmup)
    )


def schedule_settings(kind: str, total_steps: int, warmup: float) -> dict:
    """What identifies a schedule (stored beside its state in the checkpoint)."""
    return {"kind": kind, "total_steps": int(total_steps), "warmup": float(warmup)}


def check_resumable(saved: dict | None, wanted: dict, source: str) -> None:
    """ValueError unless a checkpoint's schedule `saved` can continue as `wanted`: the same
    settings, or a constant learning rate on both sides (whose run may be extended)."""
    saved = saved or schedule_settings("constant", wanted["total_steps"], wanted["warmup"])
    if saved["kind"] == wanted["kind"] == "constant":
        return
    if saved != wanted:
        raise ValueError(
            f"{source}: the checkpoint's learning-rate schedule {saved} differs from this run's "
            f"{wanted}; resume with the same --schedule, --warmup and --steps"
        )


__all__ = [
    "SCHEDULES",
    "build_scheduler",
    "check_resumable",
    "cosine_factor",
    "schedule_settings",
    "step_factor",
]
