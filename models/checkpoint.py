"""Checkpoints: plain dicts `{"family", "config", "state_dict", "meta"}`.

Never a pickled module: files load with `torch.load(weights_only=True)`. Training
checkpoints carry one more key, `"train"` (optimizer state, step, RNG states) that
`load_checkpoint` ignores and `load_training_state` returns. `"family_source"` says where the
family came from (models.registry.family_source: module, entry point, distribution), so that
loading a checkpoint whose family is missing names what to install or import.
Writes are atomic (temp file in the same folder, then rename).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import torch

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.atomic import atomic_path

from .base import DenoiserModel
from .registry import build_model, families, family_source

REQUIRED_KEYS = ("family", "config", "state_dict", "meta")


class CheckpointError(InputError):
    """A file that is not a valid rtdenoise checkpoint (message names the file)."""


def save_checkpoint(
    path: str | os.PathLike,
    model: DenoiserModel,
    meta: dict | None = None,
    train: dict | None = None,
) -> Path:
    """Write `model` (family, config, weights) and `meta` to `path` atomically.

    `train` (optional) holds what resuming needs: optimizer state, step, RNG states.
    """
    path = Path(path)
    ckpt: dict[str, Any] = {
        "family": model.family,
        "config": model.config(),
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "meta": dict(meta or {}),
        "family_source": family_source(model.family),
    }
    if train is not None:
        ckpt["train"] = train
    with atomic_path(path) as tmp:
        torch.save(ckpt, tmp)
    return path


_GLOBAL = re.compile(r"Unsupported global: GLOBAL ([\w.]+)")


def _reason(exc: Exception) -> str:
    """The informative line of a torch.load error (weights_only errors are long and suggest
    `weights_only=False`, which would run the file's code: never pass that advice on)."""
    text = str(exc)
    found = _GLOBAL.search(text)
    if found:
        return (
            f"it needs the Python object {found.group(1)}, refused: a checkpoint holds only "
            "tensors and plain data"
        )
    marker = "WeightsUnpickler error:"
    if marker in text:
        text = text.split(marker, 1)[1]
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    reason = lines[0].split(". Please")[0] if lines else type(exc).__name__
    return "cannot unpickle it safely" if "weights_only" in reason else reason


def read_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """The raw checkpoint dict, loaded with weights_only=True and checked for its keys."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle / zip errors, or a forbidden global in the pickle
        raise CheckpointError(f"{path}: not an rtdenoise checkpoint ({_reason(exc)})") from exc
    if not isinstance(ckpt, dict) or any(k not in ckpt for k in REQUIRED_KEYS):
        keys = sorted(ckpt) if isinstance(ckpt, dict) else type(ckpt).__name__
        raise CheckpointError(
            f"{path}: not an rtdenoise checkpoint (expected keys {list(REQUIRED_KEYS)}, got {keys})"
        )
    return ckpt


def model_from_checkpoint(ckpt: dict[str, Any], path: str | os.PathLike) -> DenoiserModel:
    """Build the checkpoint's model and load its weights; errors name `path`."""
    path = Path(path)
    if ckpt["family"] not in families():
        raise CheckpointError(f"{path}: {missing_family(ckpt)}")
    try:
        model = build_model(ckpt["family"], ckpt["config"])
    except (ValueError, TypeError) as exc:
        raise CheckpointError(f"{path}: {exc}") from exc
    try:
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except (RuntimeError, TypeError, AttributeError) as exc:
        first = str(exc).strip().splitlines()[0]
        raise CheckpointError(
            f"{path}: state_dict does not match the {ckpt['family']} model ({first})"
        ) from exc
    return model


def missing_family(ckpt: dict[str, Any]) -> str:
    """Why the checkpoint's family cannot be built here and how to make it importable."""
    family, source = ckpt["family"], ckpt.get("family_source") or {}
    module = source.get("module") if isinstance(source, dict) else None
    came = f" (it came from module {module}" if module else ""
    if came and source.get("distribution"):
        came += f", distribution {source['distribution']}"
    came += ")" if came else ""
    hint = f"--family-module {module}" if module else "--family-module <module>"
    return (
        f"model family {family!r} is not registered here{came}; install the package that "
        f"declares it (an entry point of group 'rtdenoise.families'), or name its code with "
        f"{hint}; known: {families()}"
    )


def load_checkpoint(path: str | os.PathLike) -> tuple[DenoiserModel, dict]:
    """(model in eval mode with its stored weights, meta); CheckpointError names the file."""
    ckpt = read_checkpoint(path)
    model = model_from_checkpoint(ckpt, path)
    model.eval()
    return model, dict(ckpt["meta"])


def load_training_state(path: str | os.PathLike) -> tuple[DenoiserModel, dict, dict]:
    """(model in train mode, meta, train state) of a training checkpoint, for resuming."""
    ckpt = read_checkpoint(path)
    if "train" not in ckpt:
        raise CheckpointError(f"{path}: checkpoint has no training state to resume from")
    model = model_from_checkpoint(ckpt, path)
    model.train()
    return model, dict(ckpt["meta"]), ckpt["train"]
