"""Weight averages of checkpoints of one lineage (a "model soup", Wortsman et al. 2022).

Two fine-tunes of the same run (e.g. a stage and the stage fine-tuned from it) lie in one basin,
and a weighted mean of their weights trades what each stage bought: nbg's dark-edge stage keeps
dark pixels beside lights dark at some cost on glass, and a blend of it with the stage before
keeps most of both (benchmarks/README.md, "More steps for the gated nbg"). Only checkpoints of
the same family and config are averaged; the result's meta lists every source's commands
(oldest first, each once) and then the averaging command.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from .base import DenoiserModel
from .checkpoint import CheckpointError, load_checkpoint
from .train import commands_of


def average_checkpoints(
    paths: Sequence[str | os.PathLike],
    weights: Sequence[float],
    command: str | None = None,
) -> tuple[DenoiserModel, dict]:
    """(model with sum_i weights[i] * weights of paths[i], meta). The weights must be >= 0
    and sum to 1; every checkpoint must share the first one's family and config."""
    if len(paths) < 2 or len(paths) != len(weights):
        raise ValueError(f"needs two or more checkpoints, one weight each: {paths}, {weights}")
    if min(weights) < 0 or abs(sum(weights) - 1.0) > 1e-6:
        raise ValueError(f"weights must be >= 0 and sum to 1, got {list(weights)}")
    loaded = [load_checkpoint(p) for p in paths]
    model, _ = loaded[0]
    for path, (other, _) in zip(paths[1:], loaded[1:], strict=True):
        if other.family != model.family or other.config() != model.config():
            raise CheckpointError(
                f"{path}: {other.family} {other.config()} is not {paths[0]}'s "
                f"{model.family} {model.config()}; only one model's checkpoints average"
            )
    states = [m.state_dict() for m, _ in loaded]
    averaged = {
        key: sum(w * s[key].double() for w, s in zip(weights, states, strict=True)).to(value.dtype)
        if value.is_floating_point()
        else value
        for key, value in states[0].items()
    }
    model.load_state_dict(averaged)
    commands: list[str] = []
    for _, meta in loaded:
        commands += [c for c in commands_of(meta) if c not in commands]
    sources = [
        {"path": str(Path(p)), "weight": float(w), "step": meta.get("step")}
        for p, w, (_, meta) in zip(paths, weights, loaded, strict=True)
    ]
    meta = {"averaged_from": sources, "commands": commands + ([command] if command else [])}
    return model, meta


__all__ = ["average_checkpoints"]
