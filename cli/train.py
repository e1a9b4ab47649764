"""`denoise-train`: train a denoiser on EXR sequences and write a checkpoint."""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from rtdenoise.cli.common import (
    CONTEXT_SETTINGS,
    FamilyModuleOption,
    VersionOption,
    fail,
    family_names,
    load_family_modules,
    one_line_warnings,
    passive_openmp_threads,
    user_errors,
)
from rtdenoise.runtime.sequences.layouts import LAYOUTS, get_layout

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode="markdown",
    context_settings=CONTEXT_SETTINGS,
)


class Loss(str, Enum):
    """models.losses.LOSSES (named here without importing torch)."""

    paper = "paper"
    smape = "smape"
    l1_ms_ssim = "l1-ms-ssim"


class Schedule(str, Enum):
    """models.schedule.SCHEDULES."""

    constant = "constant"
    onecycle = "onecycle"
    cosine = "cosine"
    step = "step"


class Recipe(str, Enum):
    """models.recipes.RECIPE_NAMES."""

    default = "default"
    paper = "paper"
    oidn = "oidn"


# TrainSettings field filled by a recipe -> the option that sets it here
_RECIPE_OPTIONS = {
    "lr": "lr",
    "batch": "batch",
    "crop": "crop",
    "flips": "flips",
    "rotations": "rotations",
    "brightness": "brightness",
    "sample_counts": "samples",
    "schedule": "schedule",
    "temporal_weight": "temporal_weight",
    "loss": "loss",
    "permute": "permute_channels",
    "exposure": "exposure",
}


def _given(ctx: typer.Context, option: str) -> bool:
    """Whether `option` was set on the command line (or by an environment variable)."""
    source = ctx.get_parameter_source(option)
    return source is not None and source.name not in ("DEFAULT", "DEFAULT_MAP")


class Exposure(str, Enum):
    """models.data.EXPOSURES."""

    none = "none"
    auto = "auto"


def _parse_config(text: str | None) -> dict | None:
    if text is None:
        return None
    source = Path(text)
    try:
        data = json.loads(source.read_text() if source.is_file() else text)
    except json.JSONDecodeError as exc:
        fail(f"--config: not a JSON object or JSON file ({exc})")
    if not isinstance(data, dict):
        fail("--config: expected a JSON object such as '{\"widths\": [16, 24, 32]}'")
    return data


def _parse_counts(text: str) -> tuple[int, ...]:
    try:
        counts = tuple(int(v) for v in text.split(","))
    except ValueError:
        counts = ()
    if not counts or min(counts) < 1:
        fail(f"--samples: expected counts >= 1 such as 1,2,4, got {text!r}")
    return counts


def _parse_oversample(items: list[str] | None) -> dict[str, int]:
    """["lights=3", ...] -> {"lights": 3}; fail() names a malformed item."""
    factors: dict[str, int] = {}
    for item in items or []:
        kind, sep, count = item.partition("=")
        try:
            n = int(count)
        except ValueError:
            n = 0
        if not sep or not kind.strip() or n < 1:
            fail(f"--oversample {item!r}: expected KIND=N with N >= 1 (e.g. lights=3)")
        factors[kind.strip()] = n
    return factors


def _parse_range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        fail(f"--brightness: expected 'LOW,HIGH' such as 0.8,1.2, got {text!r}")
    if not 0 < lo <= hi:
        fail(f"--brightness: need 0 < LOW <= HIGH, got {text!r}")
    return lo, hi


@app.command()
def train_command(
    ctx: typer.Context,
    sequences: Annotated[
        list[Path],
        typer.Argument(
            metavar="SEQ_DIR",
            help="Training sequence folders (in the --layout's channels), or folders of them "
            "(a set denoise-render wrote: its complete sequences).",
        ),
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Checkpoint to write (.pt).")],
    family: Annotated[
        str,
        typer.Option(
            help="Model family: " + ", ".join(family_names()) + ", or one of --family-module."
        ),
    ] = "afn",
    family_module: FamilyModuleOption = None,
    layout: Annotated[
        str,
        typer.Option(
            "--layout",
            "-l",
            help="Channel layout of the training and --val sequences, as denoise-run reads "
            "them: a preset (" + ", ".join(LAYOUTS) + ") or a layout file `my_renderer.toml` "
            "(docs/layouts.md).",
        ),
    ] = "canonical",
    steps: Annotated[int, typer.Option(min=1, help="Total optimisation steps.")] = 1000,
    crop: Annotated[
        int, typer.Option(min=8, help="Square crop side in pixels (at most the frame size).")
    ] = 128,
    frames: Annotated[int, typer.Option(min=1, help="Frames per clip.")] = 8,
    batch: Annotated[int, typer.Option(min=1, help="Clips per step.")] = 4,
    lr: Annotated[float, typer.Option(min=0.0, help="Adam learning rate.")] = 1e-3,
    seed: Annotated[int, typer.Option(help="Seed of torch, numpy and python RNGs.")] = 0,
    resume: Annotated[
        Path | None, typer.Option(help="Continue from this training checkpoint.")
    ] = None,
    init_from: Annotated[
        str | None,
        typer.Option(
            metavar="CHECKPOINT",
            help="Fine-tune: start a new run from this checkpoint's weights (a .pt file or "
            "demo:<family>); --config changes its config where the weights keep their shapes "
            "(e.g. Isik21's deployment step: --config '{\"leaky_slope\": 0}') or gain input "
            "channels, which start at zero (e.g. nbg's --config '{\"history_input\": true}').",
        ),
    ] = None,
    val: Annotated[
        list[Path] | None,
        typer.Option(help="Validation sequence folder (repeatable): PSNR at the end."),
    ] = None,
    temporal_weight: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="Weight of the temporal term (temporal SMAPE; for l1-ms-ssim the L1 of frame "
            "differences).",
        ),
    ] = 0.25,
    relmse_weight: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="Add this multiple of relMSE ((o - t)^2 / (t^2 + 0.01), the benchmarks' metric) "
            "to --loss: unlike SMAPE it does not saturate, so a small bright light smeared into "
            "dark neighbours costs what it costs in the metric (0: off).",
        ),
    ] = 0.0,
    rel_l1_weight: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="Add this multiple of relative L1 (|o - t| / (|t| + 0.1)) to --loss: as "
            "unsaturated as relMSE, with a gradient bounded by 10 per pixel, so a few smeared "
            "pixels do not swamp the rest of the batch (0: off).",
        ),
    ] = 0.0,
    dark_edge_weight: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="Add this multiple of the relative L1 of the dark pixels beside bright ones "
            "(reference at most 1/20 of the brightest within 2 px, that one >= 0.5), zero "
            "elsewhere, averaged over all pixels: where a kernel smears a small light into its "
            "dark neighbours (0: off).",
        ),
    ] = 0.0,
    first_frame_weight: Annotated[
        float,
        typer.Option(
            min=0.0,
            help="Add this multiple of the loss (temporal term off) on each clip's first frame, "
            "the one that starts without history as a shot's first frame does: where a "
            "temporal model is weakest (0: off).",
        ),
    ] = 0.0,
    oversample: Annotated[
        list[str] | None,
        typer.Option(
            metavar="KIND=N",
            help="Draw the sequences whose meta.json kind is KIND (denoise-render's scene "
            "kinds: lights, glass, ...) N times as often; repeatable.",
        ),
    ] = None,
    brightness: Annotated[
        str, typer.Option(help="Random brightness range LOW,HIGH (1,1 disables).")
    ] = "0.8,1.2",
    flips: Annotated[bool, typer.Option(help="Random horizontal / vertical flips.")] = True,
    save_every: Annotated[
        int, typer.Option(min=0, help="Checkpoint every N steps (0: only at the end).")
    ] = 500,
    threads: Annotated[int, typer.Option(min=1, help="torch intra-op threads.")] = 2,
    device: Annotated[
        str,
        typer.Option(help="Where to train: cpu, cuda or cuda:N (the model and every batch)."),
    ] = "cpu",
    config: Annotated[
        str | None,
        typer.Option(help="Model config overrides: a JSON object or a JSON file."),
    ] = None,
    progress: Annotated[
        bool,
        typer.Option(
            help="A progress bar with the ETA on a terminal; elsewhere (a log, a pipe) and "
            "with --no-progress a line per --log-every steps with the ETA."
        ),
    ] = True,
    samples: Annotated[
        str | None,
        typer.Option(
            help="Per-sample models: sample counts S drawn per batch, e.g. 1,2,4 (default: all)."
        ),
    ] = None,
    loss: Annotated[
        Loss,
        typer.Option(
            help="paper: the family's own loss (SMAPE + temporal SMAPE for afn / wskp, Isik21 "
            "eq. 9 for affinity, Meng20's gamma L1 for nbg; crossreg, pretrained offline with "
            "its online update frozen: SMAPE + temporal SMAPE); smape: SMAPE + temporal SMAPE for "
            "any family; l1-ms-ssim: Open Image Denoise's 0.16 L1 + 0.84 (1 - MS-SSIM) on a "
            "PU-like curve of the auto-exposed colours, + --temporal-weight x the L1 of frame "
            "differences."
        ),
    ] = Loss.paper,
    rotations: Annotated[
        bool,
        typer.Option(help="Random 90-degree rotations (motion and normals turn with them)."),
    ] = False,
    permute_channels: Annotated[
        bool,
        typer.Option(
            help="Random permutation of R, G, B (the same for color, albedo, reference, samples)."
        ),
    ] = False,
    exposure: Annotated[
        Exposure,
        typer.Option(
            help="auto: scale each clip's radiance and reference to the auto-exposure of its "
            "noisy colour (key 0.18) before --brightness; none: raw renderer values."
        ),
    ] = Exposure.none,
    schedule: Annotated[
        Schedule,
        typer.Option(
            help="Learning rate over --steps: constant --lr; onecycle (lr/25 -> --lr over "
            "--warmup, cosine down to lr/25/1e4); cosine (linear warm-up, cosine decay); step "
            "(x 0.75 after every fifth of --steps, Isik21)."
        ),
    ] = Schedule.constant,
    warmup: Annotated[
        float,
        typer.Option(min=0.0, max=0.99, help="Warm-up fraction of --steps (onecycle, cosine)."),
    ] = 0.15,
    stop_at: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Stop after this step (the schedule still spans --steps); continue later with "
            "--resume: a long run in pieces.",
        ),
    ] = None,
    cache: Annotated[
        Path | None,
        typer.Option(
            help="Convert the sequences once into this folder (.npy) and memory-map them: "
            "training sets larger than memory."
        ),
    ] = None,
    workers: Annotated[
        int,
        typer.Option(
            min=0,
            help="Processes drawing batches ahead (a GPU run needs them). >= 1: batch k comes "
            "from its own random stream (seed, k), the same for any count; 0: one stream in "
            "this process (how the demos were trained).",
        ),
    ] = 0,
    log_every: Annotated[
        int, typer.Option(min=1, help="Steps per line of progress and loss history entry.")
    ] = 50,
    recipe: Annotated[
        Recipe,
        typer.Option(
            help="Settings to start from: default (the options' defaults, how the demos were "
            "trained); paper (the family's own paper recipe: its loss, learning rate and "
            "schedule, batch, crop and augmentation; Fan21's input clip and SMAPE eps for wskp; "
            "not crossreg, which learns online: the default recipe pretrains its initial theta "
            "with the online update frozen); oidn (Open Image Denoise's: l1-ms-ssim, "
            "onecycle, rotations, channel permutation, auto exposure, batch 16). Options given "
            "explicitly override the recipe's; the checkpoint meta records it."
        ),
    ] = Recipe.default,
    flush_denormals: Annotated[
        bool,
        typer.Option(
            "--flush-denormals/--keep-denormals",
            help="Flush denormal floats to zero in this process (torch.set_flush_denormal, "
            "x86): Intel cores compute each denormal with a microcode assist, and Isik21's "
            "training steps ran 1.8x faster with them flushed on an Intel Xeon; results move by "
            "less than 1.2e-38 a value. --keep-denormals: IEEE gradual underflow.",
        ),
    ] = True,
    version: VersionOption = False,
) -> None:
    """Train a denoiser on EXR sequences and write a checkpoint.

    Each SEQ_DIR holds frame_NNNN.exr and ref_NNNN.exr (the reference). In the canonical
    layout (the default) a frame has R,G,B noisy radiance, albedo.R/G/B, normal.X/Y/Z,
    depth.Z, motion.X/Y in pixels with previous = current + motion, x right, y down; --layout
    reads any other as denoise-run does (blender, or a layout file), converted at load time.

    Every step draws --batch clips of --frames consecutive frames with one random --crop,
    flip (and with --rotations a quarter turn, with --permute-channels a colour permutation)
    and brightness per clip, unrolls the model over the clip (state carried, reset on its
    first frame) and minimises --loss (default: the family's own, e.g. SMAPE (Lee24 eq. 5) +
    --temporal-weight x temporal SMAPE (Isik21 eq. 12)) with Adam under --schedule. The
    checkpoint {family, config, state_dict, meta} is written atomically every --save-every
    steps and at the end; its meta holds this command line and every setting; --resume
    continues a run exactly (optimizer, schedule and RNG states); --init-from starts a new
    run from a checkpoint's weights (fine-tuning a shipped demo on your own frames:
    --init-from demo:wskp). Needs the train extra (torch).

    OIDN-like recipe: --loss l1-ms-ssim --schedule onecycle --rotations --permute-channels
    --crop 256 --batch 16 --cache DIR --workers 8.
    """
    if resume is not None and init_from is not None:
        fail("--resume continues a run, --init-from starts a new one from weights: give one")
    model_config = _parse_config(config)
    brightness_range = _parse_range(brightness)
    oversample_factors = _parse_oversample(oversample)
    sample_counts = _parse_counts(samples) if samples else ()
    with user_errors():
        get_layout(layout)  # a typo or a bad layout file fails before torch loads
    with user_errors(extra="train"):
        import torch

        from rtdenoise.models.recipes import recipe_settings
        from rtdenoise.models.train import TrainSettings, train

        from .export import resolve_checkpoint

        load_family_modules(family_module)
        try:
            recipe_values, recipe_config = recipe_settings(recipe.value, family)
        except ValueError as exc:
            fail(str(exc))
        if recipe_config:
            model_config = recipe_config | (model_config or {})
        overrides = {
            field: value
            for field, value in recipe_values.items()
            if not _given(ctx, _RECIPE_OPTIONS[field])
        }
        settings = TrainSettings(
            steps=steps,
            crop=crop,
            frames=frames,
            batch=batch,
            lr=lr,
            seed=seed,
            temporal_weight=temporal_weight,
            brightness=brightness_range,
            flips=flips,
            save_every=save_every,
            threads=threads,
            sample_counts=sample_counts,
            device=device,
            loss=loss.value,
            relmse_weight=relmse_weight,
            rel_l1_weight=rel_l1_weight,
            dark_edge_weight=dark_edge_weight,
            first_frame_weight=first_frame_weight,
            rotations=rotations,
            permute=permute_channels,
            exposure=exposure.value,
            schedule=schedule.value,
            warmup=warmup,
            stop_at=stop_at,
            cache=str(cache) if cache is not None else None,
            log_every=log_every,
            workers=workers,
            recipe=recipe.value,
            layout=layout,
            oversample=oversample_factors,
        )
        settings = dataclasses.replace(settings, **overrides)
        flushed_before = torch.tensor([1e-39]).item() == 0.0  # the mode as it came
        if flush_denormals:  # before torch starts its worker threads, which inherit the mode
            torch.set_flush_denormal(True)
        try:
            result = train(
                sequences,
                output,
                family=family,
                model_config=model_config,
                settings=settings,
                resume=resume,
                init_from=resolve_checkpoint(init_from) if init_from is not None else None,
                val_dirs=val or [],
                progress=progress,
                command=shlex.join(["denoise-train", *sys.argv[1:]]),
                log=lambda line: print(line, flush=True),
            )
        finally:  # an in-process caller (a test, a notebook) gets its mode back
            torch.set_flush_denormal(flushed_before)
    last = result.losses[-1] if result.losses else float("nan")
    print(
        f"wrote {result.checkpoint} at step {result.step} (last loss {last:.4f}, "
        f"{result.seconds_per_step:.3f} s/step)"
    )


def main() -> None:
    """Console-script entry point."""
    one_line_warnings()
    passive_openmp_threads()
    app()


if __name__ == "__main__":
    main()
