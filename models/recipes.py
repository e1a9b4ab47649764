"""Training recipes: named sets of `denoise-train` settings (and model config overrides).

- `default`: the settings `denoise-train` has without a recipe (how the demos were trained).
- `paper`: each family's own recipe, as its paper (or official code) states it; what a paper
  leaves open keeps the default and is named in `PAPER_GAPS`. Every family trains here on
  clips of --frames frames with the state carried, not on single frames with a precomputed
  temporal accumulation (Lee24, Fan21): a deviation of all recipes (docs/families/*.md).
- `oidn`: Open Image Denoise's public training recipe (issue 31): L1 + MS-SSIM on a perceptual
  transfer of auto-exposed colours, OneCycle, flips, quarter turns and RGB permutation, batch 16.
  OIDN crops 256 x 256; the recipe crops 128, the side of the data engine's training clips.

A recipe only fills the options a command line leaves unset; any option given explicitly wins.
No torch here: the CLI reads it before importing the trainer.
"""

from __future__ import annotations

RECIPE_NAMES = ("default", "paper", "oidn")

# TrainSettings field -> value; "config" holds model config overrides
_PAPER: dict[str, dict] = {
    # Isik21 s.5: Adam 1e-4, batch 4, flips and 90-degree rotations, 128^2 crops, 8-frame clips
    # with S in {1, 2, 4}; lr x 0.75 every 150 of about 750 epochs (schedule "step"); the loss
    # (SMAPE + 0.25 temporal SMAPE + regulariser, eq. 9) is the family's `paper` loss.
    "affinity": {
        "lr": 1e-4,
        "batch": 4,
        "crop": 128,
        "flips": True,
        "rotations": True,
        "brightness": (1.0, 1.0),
        "sample_counts": (1, 2, 4),
        "schedule": "step",
        "temporal_weight": 0.25,
        "loss": "paper",
    },
    # Lee24 s.IV-B: 128^2 crops, flips, brightness in [0.8, 1.2], Adam 1e-3, batch 16,
    # SMAPE (eq. 5) alone
    "afn": {
        "lr": 1e-3,
        "batch": 16,
        "crop": 128,
        "flips": True,
        "rotations": False,
        "brightness": (0.8, 1.2),
        "schedule": "constant",
        "temporal_weight": 0.0,
        "loss": "paper",
    },
    # Fan21's official code: batch 64, flips and quarter turns, no brightness change, SMAPE with
    # eps 1e-2 alone, network input clamp(x, 0, 1) ** (1 / 2.2)
    "wskp": {
        "batch": 64,
        "crop": 128,
        "flips": True,
        "rotations": True,
        "brightness": (1.0, 1.0),
        "schedule": "constant",
        "temporal_weight": 0.0,
        "loss": "paper",
        "config": {"input_clip": True, "smape_eps": 1e-2},
    },
    # Meng20 s.5: Adam 1e-4, batch 20, 128^2 crops, L1 on gamma-mapped images (eq. 14); no
    # augmentation named
    "nbg": {
        "lr": 1e-4,
        "batch": 20,
        "crop": 128,
        "flips": False,
        "rotations": False,
        "brightness": (1.0, 1.0),
        "schedule": "constant",
        "temporal_weight": 0.0,
        "loss": "paper",
    },
}

# what a paper leaves open, kept at the default (said in the checkpoint meta and the docs)
PAPER_GAPS = {
    "wskp": "Fan21 names no learning rate: Adam at the default 1e-3",
}

_OIDN = {
    "loss": "l1-ms-ssim",
    "schedule": "onecycle",
    "rotations": True,
    "permute": True,
    "flips": True,
    "exposure": "auto",
    "crop": 128,
    "batch": 16,
}


def recipe_settings(name: str, family: str) -> tuple[dict, dict]:
    """(TrainSettings values, model config overrides) of recipe `name` for `family`.
    ValueError for an unknown recipe, or `paper` for a family without an offline recipe."""
    if name not in RECIPE_NAMES:
        raise ValueError(f"unknown recipe {name!r}; choose one of {', '.join(RECIPE_NAMES)}")
    if name == "default":
        return {}, {}
    if name == "oidn":
        return dict(_OIDN), {}
    if family not in _PAPER:
        known = ", ".join(sorted(_PAPER))
        why = (
            "Choi24 trains online only, while it runs (there is no offline recipe to follow; "
            "the default recipe pretrains its initial theta, the online update frozen)"
            if family == "crossreg"
            else "no paper recipe is recorded for it"
        )
        raise ValueError(f"--recipe paper: family {family!r}: {why}; paper recipes: {known}")
    values = dict(_PAPER[family])
    config = values.pop("config", {})
    return values, dict(config)


__all__ = ["PAPER_GAPS", "RECIPE_NAMES", "recipe_settings"]
