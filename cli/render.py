"""`denoise-render`: render random animated scenes with Mitsuba 3 into canonical EXR sequences."""

from __future__ import annotations

import sys
import time
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

from ..datagen.cluster import render_index, sequence_name, set_render_threads
from ..datagen.kinds import allowed_kinds, describe_kinds
from ..datagen.render import RenderConfig
from ..datagen.shards import parse_shard, release, shard_indices, try_lock
from ..datagen.variant import SUPPORTED_VARIANTS, select_variant
from ..runtime.errors import InputError
from .cluster import (
    DEFAULT_RETRIES,
    ClusterAddressOption,
    ClusterOption,
    RetriesOption,
    report_failures,
    task_progress,
)
from .common import (
    CONTEXT_SETTINGS,
    EXIT_BAD_INPUT,
    VersionOption,
    fail,
    one_line_warnings,
    parse_size,
    user_errors,
)

HELP = """Render N random animated scenes (Mitsuba 3 path tracer) into OUT_DIR/seq_XXX/,
one folder per sequence, XXX = sequence index.

\b
Each sequence is one scene kind (--list-kinds: rooms, corridors, closed boxes lit
by hidden lights, glass, water, thin geometry, fine textures, lights in view,
objects), drawn from its seed with the kinds' weights among --kinds minus
--exclude-kinds, and one camera path (still, pan, dolly, orbit, fast) or two
shots with a cut between them: meta.json lists the cut frames (`cuts`, and
`reset` per camera); motion is 0 there, as on frame 0. A shot whose frame 0 is
black or whose camera enters a shape is drawn again (meta.json `redraws`).

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
  meta.json       seeds, cameras, cuts, scene, conventions (written last: a
                  folder without it is incomplete)
  partial.json    while it renders: a killed job resumes from it, keeping
                  the whole frames and rendering the rest with the same seeds

Sequence i uses a scene seed derived from (--seed, i), so a job can be split:
e.g. `--sequences 12 --start-index 0` and `--sequences 12 --start-index 12`
give the same 24 sequences as one run, and so do N processes started at once
with `--shard 0/N` ... `--shard N-1/N` (shard I takes the indices i with
i % N == I). Complete folders are skipped unless --overwrite; a half-written
one is finished. A lock file (seq_XXX/.lock) keeps processes whose ranges
overlap off each other's sequences. Needs the data extra (mitsuba).

With --cluster each sequence is one Ray task (the cluster extra; docs/cluster.md),
seeded as locally, so the data set is the same either way; OUT_DIR must be on a
file system every node shares. A sequence that fails is named, the others finish,
and the exit code is non-zero.
"""

app = typer.Typer(add_completion=False, rich_markup_mode=None, context_settings=CONTEXT_SETTINGS)
console = Console(stderr=True)


def _warn(message: str) -> None:
    """A yellow `warning: ...` line; the message is not read as markup (`[data]` stays)."""
    console.print(f"warning: {message}", style="yellow", markup=False, highlight=False)


def _kind_list(text: str | None) -> tuple[str, ...] | None:
    if text is None:
        return None
    return tuple(k.strip() for k in text.split(",") if k.strip())


def _list_kinds(value: bool) -> None:
    if value:
        print(describe_kinds())
        raise typer.Exit()


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
    references_from: Annotated[
        Path | None,
        typer.Option(
            "--references-from",
            help="A set rendered before from the same --seed, kinds, size, frames, --spp-ref and "
            "variant: copy its sequences' references instead of rendering them (they are most "
            "of the time), e.g. to render that set's inputs again with --samples. Each "
            "sequence's scene, cameras, spp and renderer are checked against it, and its "
            "exposure is taken.",
        ),
    ] = None,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Re-render complete ones.")
    ] = False,
    threads: Annotated[
        int | None,
        typer.Option(
            "--threads",
            min=1,
            help="Render threads per sequence (default: all cores); with --cluster also the "
            "CPUs Ray reserves for each (default there: 1).",
        ),
    ] = None,
    cluster: ClusterOption = False,
    cluster_address: ClusterAddressOption = None,
    retries: RetriesOption = DEFAULT_RETRIES,
    kinds: Annotated[
        str | None,
        typer.Option(
            "--kinds",
            help="Comma-separated scene kinds to draw from (default: every kind of weight > 0; "
            "see --list-kinds). A seed's kind depends on this set.",
        ),
    ] = None,
    exclude_kinds: Annotated[
        str | None,
        typer.Option(
            "--exclude-kinds",
            help="Comma-separated scene kinds never drawn (e.g. the ones held out for validation).",
        ),
    ] = None,
    shard: Annotated[
        str | None,
        typer.Option(
            "--shard",
            help="I/N: render only the indices i of the range with i % N == I, so that N "
            "processes share one job and folder.",
        ),
    ] = None,
    list_kinds: Annotated[
        bool,
        typer.Option(
            "--list-kinds",
            callback=_list_kinds,
            is_eager=True,
            help="List the scene kinds and their weights, then exit.",
        ),
    ] = False,
    version: VersionOption = False,
) -> None:
    if size is not None:
        with user_errors():
            width, height = parse_size(size)
    try:
        shard_ij = parse_shard(shard) if shard is not None else None
        kind_set = _kind_list(kinds)
        excluded = _kind_list(exclude_kinds) or ()
        allowed_kinds(kind_set, excluded)
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None
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
    if references_from is not None and not references_from.is_dir():
        raise typer.BadParameter(f"--references-from {references_from}: no such folder")
    if references_from is not None and references_from.resolve() == out_dir.resolve():
        raise typer.BadParameter("--references-from must be another folder than OUT_DIR")
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
        kinds=kind_set,
        exclude_kinds=tuple(excluded),
    )
    indices = shard_indices(range(start_index, start_index + sequences), shard_ij)
    todo = [
        i for i in indices if overwrite or not (out_dir / sequence_name(i) / "meta.json").is_file()
    ]
    if len(todo) < len(indices):
        console.print(f"skipping {len(indices) - len(todo)} complete sequence(s) (use --overwrite)")
    if references_from is not None:
        lent = [i for i in todo if (references_from / sequence_name(i) / "meta.json").is_file()]
        if len(lent) < len(todo):
            console.print(
                f"leaving out {len(todo) - len(lent)} sequence(s) not complete in "
                f"{references_from} (no references to copy yet)"
            )
        todo = lent
    start = time.perf_counter()
    if cluster or cluster_address is not None:
        _render_cluster(
            out_dir, todo, seed, cfg, used, threads, cluster_address, retries, references_from
        )
        done = len(todo)
    else:
        set_render_threads(threads)
        try:
            done = _render_local(out_dir, todo, seed, cfg, used, overwrite, references_from)
        except InputError as exc:  # a source whose shots are not these (--references-from)
            fail(exc, EXIT_BAD_INPUT)
    console.print(
        f"rendered {done} sequence(s) of {frames} frame(s) at {width}x{height}, "
        f"{spp_ref} spp references, variant {used}, in {time.perf_counter() - start:.1f} s "
        f"-> {out_dir}",
        soft_wrap=True,
    )


def _render_local(
    out_dir: Path,
    todo: list[int],
    seed: int,
    cfg: RenderConfig,
    variant: str,
    overwrite: bool,
    references_from: Path | None = None,
) -> int:
    """Render `todo` one after the other (each under its lock); returns how many were rendered.
    Progress: rich's bar on a terminal, else one plain line per sequence (rate and ETA)."""
    plain = not console.is_terminal
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    done = skipped = 0
    t0 = time.perf_counter()
    with Progress(*columns, console=console, disable=plain) as progress:
        task = progress.add_task("render", total=len(todo) * cfg.frames)
        for n, i in enumerate(todo):
            name = sequence_name(i)
            lock = try_lock(out_dir / name)
            if lock is None:
                skipped += 1
                _say(plain, f"{name}: another process is rendering it, skipped")
                progress.advance(task, cfg.frames)
                continue
            try:
                progress.update(task, description=name)
                ts = time.perf_counter()
                if (out_dir / name / "meta.json").is_file() and not overwrite:
                    progress.advance(task, cfg.frames)  # finished by another process meanwhile
                    continue
                meta = render_index(
                    out_dir,
                    i,
                    seed,
                    cfg,
                    variant,
                    on_frame=lambda _t: progress.advance(task),
                    on_warning=_warn,
                    references_from=references_from,
                )
            finally:
                release(lock)
            done += 1
            elapsed = time.perf_counter() - t0
            eta = elapsed / (n + 1) * (len(todo) - n - 1)
            _say(
                plain,
                f"{name} ({meta.get('kind')}) {time.perf_counter() - ts:.1f} s; {n + 1}/{len(todo)}"
                f", {3600.0 * done / max(elapsed, 1e-9):.1f} sequences/h, ETA {eta / 60:.1f} min",
            )
    if skipped:
        console.print(f"skipped {skipped} sequence(s) another process holds")
    return done


def _say(plain: bool, message: str) -> None:
    if plain:
        print(message, file=sys.stderr, flush=True)


def _render_cluster(
    out_dir: Path,
    todo: list[int],
    seed: int,
    cfg: RenderConfig,
    variant: str,
    threads: int | None,
    address: str | None,
    retries: int,
    references_from: Path | None = None,
) -> None:
    """--cluster: one Ray task per sequence; exits non-zero when some failed."""
    from ..datagen.cluster import render_sequences

    totals = {sequence_name(i): cfg.frames for i in todo}
    with user_errors(extra="cluster"), task_progress(console, totals, "render") as callbacks:
        outcomes = render_sequences(
            out_dir,
            todo,
            seed,
            cfg,
            variant,
            threads=threads,
            max_retries=retries,
            address=address,
            on_progress=callbacks[0],
            on_done=callbacks[1],
            references_from=references_from,
        )
    for o in outcomes:
        for message in o.warnings:
            _warn(f"{o.name}: {message}")
        if o.ok and o.result != variant:
            _warn(f"{o.name}: rendered with {o.result}, not {variant}, on its node")
    code = report_failures(outcomes, "sequence")
    if code:
        raise typer.Exit(code)


def main() -> None:
    """Console-script entry point."""
    one_line_warnings()
    app()


if __name__ == "__main__":
    main()
