"""`denoise-render`: render random animated scenes with Mitsuba 3 into canonical EXR sequences."""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from ..datagen.render import RenderConfig, derive_seed, render_sequence
from ..datagen.variant import SUPPORTED_VARIANTS, select_variant
from .common import VersionOption, one_line_warnings, parse_size, user_errors

HELP = """Render N random animated scenes (camera orbit, Mitsuba 3 path tracer) into
OUT_DIR/seq_XXX/, one folder per sequence, XXX = sequence index.

\b
Each folder holds, for frame NNNN (0-based):
  frame_NNNN.exr  R,G,B noisy 1 spp | colorB.R/G/B second 1-spp estimate
                  albedo.R/G/B | normal.X/Y/Z (camera space: x right, y up,
                  z towards the camera) | depth.Z (planar, background 1e4)
                  motion.X/Y (pixels; previous = current + motion; y down)
                  with --samples S: sample<i>.R/G/B, sample<i>.albedo.R/G/B,
                  sample<i>.normal.X/Y/Z, sample<i>.depth.Z for i < S (S
                  independent 1-spp samples); R,G,B is then their mean
  ref_NNNN.exr    R,G,B reference with --spp-ref samples per pixel
  meta.json       seeds, cameras, scene, conventions (written last: a folder
                  without it is incomplete and is rendered again)

Sequence i uses a scene seed derived from (--seed, i), so a job can be split:
e.g. `--sequences 12 --start-index 0` and `--sequences 12 --start-index 12`
give the same 24 sequences as one run. Complete folders are skipped unless
--overwrite. Needs the data extra (mitsuba).
"""

app = typer.Typer(add_completion=False, rich_markup_mode=None)
console = Console(stderr=True)


def _warn(message: str) -> None:
    """A yellow `warning: ...` line; the message is not read as markup (`[data]` stays)."""
    console.print(f"warning: {message}", style="yellow", markup=False, highlight=False)


def _check_range(name: str, value: int, lo: int, hi: int) -> None:
    if not lo <= value <= hi:
        raise typer.BadParameter(f"{name} must be in [{lo}, {hi}], got {value}")


@app.command(help=HELP)
def render(
    out_dir: Annotated[Path, typer.Argument(help="Output folder (created); gets seq_XXX/.")],
    sequences: Annotated[int, typer.Option("--sequences", "-n", help="Sequences to render.")] = 1,
    frames: Annotated[int, typer.Option("--frames", "-f", help="Frames per sequence.")] = 8,
    size: Annotated[str | None, typer.Option(help="WIDTHxHEIGHT, e.g. 128x128.")] = None,
    width: Annotated[int, typer.Option(help="Image width (ignored with --size).")] = 64,
    height: Annotated[int, typer.Option(help="Image height (ignored with --size).")] = 64,
    spp_ref: Annotated[int, typer.Option("--spp-ref", help="Samples per pixel of refs.")] = 1024,
    seed: Annotated[int, typer.Option(help="Base seed; sequence i uses derive(seed, i).")] = 0,
    start_index: Annotated[
        int, typer.Option("--start-index", help="Index of the first sequence.")
    ] = 0,
    variant: Annotated[
        str, typer.Option(help=f"Mitsuba variant: {' | '.join(SUPPORTED_VARIANTS)}.")
    ] = "scalar_rgb",
    float32: Annotated[
        bool, typer.Option("--float", help="Store float32 instead of float16.")
    ] = False,
    max_depth: Annotated[int, typer.Option("--max-depth", help="Path tracer max depth.")] = 6,
    samples: Annotated[
        int,
        typer.Option(
            "--samples", help="Write S per-sample layers (S 1-spp samples; color = their mean)."
        ),
    ] = 0,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Re-render complete ones.")
    ] = False,
    version: VersionOption = False,
) -> None:
    if size is not None:
        with user_errors():
            width, height = parse_size(size)
    _check_range("--sequences", sequences, 1, 100_000)
    _check_range("--frames", frames, 1, 100_000)
    _check_range("width", width, 8, 16384)
    _check_range("height", height, 8, 16384)
    _check_range("--spp-ref", spp_ref, 1, 1 << 20)
    _check_range("--start-index", start_index, 0, 999_999)
    _check_range("--max-depth", max_depth, 1, 64)
    _check_range("--samples", samples, 0, 64)
    if variant not in SUPPORTED_VARIANTS:
        raise typer.BadParameter(f"--variant must be one of {SUPPORTED_VARIANTS}, got {variant!r}")
    if out_dir.exists() and not out_dir.is_dir():
        raise typer.BadParameter(f"{out_dir} exists and is not a folder")
    with user_errors(extra="data"):
        used = select_variant(variant, warn=_warn)

    cfg = RenderConfig(
        width=width,
        height=height,
        frames=frames,
        spp_ref=spp_ref,
        max_depth=max_depth,
        half=not float32,
        samples=samples,
    )
    indices = range(start_index, start_index + sequences)
    todo = [
        i for i in indices if overwrite or not (out_dir / f"seq_{i:03d}" / "meta.json").is_file()
    ]
    if len(todo) < sequences:
        console.print(f"skipping {sequences - len(todo)} complete sequence(s) (use --overwrite)")
    start = time.perf_counter()
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console) as progress:
        task = progress.add_task("render", total=len(todo) * frames)
        for i in todo:
            progress.update(task, description=f"seq_{i:03d}")
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", RuntimeWarning)
                render_sequence(
                    out_dir / f"seq_{i:03d}",
                    derive_seed(seed, i),
                    cfg,
                    variant=used,
                    on_frame=lambda _t: progress.advance(task),
                    meta_extra={"job": {"base_seed": seed, "index": i}},
                )
            for w in caught:
                _warn(str(w.message))
    console.print(
        f"rendered {len(todo)} sequence(s) of {frames} frame(s) at {width}x{height}, "
        f"{spp_ref} spp references, variant {used}, in {time.perf_counter() - start:.1f} s "
        f"-> {out_dir}"
    )


def main() -> None:
    """Console-script entry point."""
    one_line_warnings()
    app()


if __name__ == "__main__":
    main()
