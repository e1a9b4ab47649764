"""`denoise-run`: denoise an EXR frame sequence with a model, frame after frame.

Reads a sequence (folder, quoted glob or printf pattern), maps its channels to the
canonical buffers through a layout, runs a backend (`none` = pass-through, an .onnx
file or `demo:<family>`), writes OUT/<same name>.exr (R,G,B), and scores the output
and the noisy input against references when there are any.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from rtdenoise.cli.cluster import (
    DEFAULT_RETRIES,
    ClusterAddressOption,
    ClusterOption,
    RetriesOption,
    report_failures,
    task_progress,
)
from rtdenoise.cli.common import (
    CONTEXT_SETTINGS,
    VersionOption,
    one_line_warnings,
    quiet_native_output,
    user_errors,
    warn,
    write_json,
)
from rtdenoise.cli.progress import kernel_compilation, plain_line
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.memory import tune_allocator
from rtdenoise.runtime.sequences.atomic import check_writable
from rtdenoise.runtime.sequences.backend import Backend, load_backend
from rtdenoise.runtime.sequences.cluster import BackendSpec, TaskOutcome, run_shots
from rtdenoise.runtime.sequences.exr import DEFAULT_MAX_PIXELS
from rtdenoise.runtime.sequences.frames import find_frames, group_shots
from rtdenoise.runtime.sequences.layouts import LAYOUTS, Layout, get_layout, parse_overrides
from rtdenoise.runtime.sequences.run import (
    METRIC_KEYS,
    Job,
    check_out_dir,
    online_summary,
    run_sequence,
)
from rtdenoise.shipped import demo_names

# The model used when --model is not given (README, "Against Open Image Denoise"): demo:nbg,
# Meng20's bilateral grids with a history gate, the highest PSNR and SSIM of the shipped models
# on the unseen validation set (above OIDN high's mean, not on every sequence), worse than the
# noisy input nowhere, small lights kept in place, at 0.8-0.9x OIDN fast's time per 720p frame.
DEFAULT_MODEL = "demo:nbg"
TABLE_MAX_FRAMES = 12  # per-frame rows up to this many frames, else only the mean

_LAYOUT_HELP = "; ".join(f"**{name}**: {lay.description}" for name, lay in LAYOUTS.items())

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode="markdown",
    context_settings=CONTEXT_SETTINGS,
)


def _format(value: float | None, key: str) -> str:
    if value is None or not np.isfinite(value):
        return "inf" if value is not None and value > 0 else "-"
    return f"{value:.2f}" if key == "psnr" else f"{value:.4f}"


def run_with_progress(
    job: Job,
    backend: Backend,
    layout: Layout,
    overrides: dict[str, str],
    *,
    half: bool,
    preview: bool,
    err: Console,
    overwrite: bool = False,
    resume: bool = False,
    max_pixels: int | None = None,
) -> dict[str, Any]:
    """`run_sequence` with a progress bar on a terminal, else a plain line per frame on
    stderr (`<sequence>: frame 3/8`), and warnings on stderr."""
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        auto_refresh=False,  # no background writes while quiet_native_output() holds fd 2
        disable=not err.is_terminal,
    )
    with progress:
        task = progress.add_task(job.name, total=len(job.frames))
        count = 0

        def advance() -> None:
            nonlocal count
            progress.advance(task)
            progress.refresh()
            count += 1
            if not err.is_terminal:  # rich shows nothing there: a log still sees progress
                plain_line(f"{job.name}: frame {count}/{len(job.frames)}")

        return run_sequence(
            job,
            backend,
            layout,
            overrides,
            half=half,
            preview=preview,
            overwrite=overwrite,
            resume=resume,
            max_pixels=max_pixels,
            on_frame=advance,
            on_warning=warn,
            reading=quiet_native_output,
        )


# How the model's custom ops ran (Denoiser.bridge), as the timing line says it.
KERNELS_LABEL = {
    "native-cpp": "native-cpp (C++ rtdenoise_ops)",
    "native": "native (numba kernels)",
    "extensions": "extensions (numba kernels through onnxruntime-extensions)",
    "": "portable ONNX bodies",
}


def print_report(report: dict[str, Any], model: str, console: Console) -> None:
    """Metrics table (per-frame rows when few frames, and the mean) and a timing line."""
    scored = [r for r in report["frames"] if r["input"] is not None]
    if scored:
        table = Table(
            title=f"{report['name']}: model {model} vs reference (noisy input in brackets)",
            title_justify="left",
        )
        table.add_column("frame", justify="right")
        for label in ("PSNR dB ↑", "SSIM ↑", "SMAPE ↓", "relMSE ↓"):
            table.add_column(label, justify="right")
        if len(scored) <= TABLE_MAX_FRAMES:
            for r in scored:
                table.add_row(
                    str(r["index"]),
                    *(f"{_format(r[k], k)} ({_format(r['input'][k], k)})" for k in METRIC_KEYS),
                )
            table.add_section()
        mean, inp = report["mean"], report["input"]
        table.add_row(
            "mean", *(f"{_format(mean[k], k)} ({_format(inp[k], k)})" for k in METRIC_KEYS)
        )
        console.print(table)
        if report["trmae"] is not None and np.isfinite(report["trmae"]):
            console.print(f"TRMAE ↓ {report['trmae']:.4f} (input {inp['trmae']:.4f})")
    t = report["timing_ms"]
    where = f"{len(report['frames'])} frames {report['size'][1]}x{report['size'][0]} -> " + str(
        Path(report["frames"][0]["output"]).parent
    )
    kept = report.get("skipped", 0)
    if t["denoise"] is None:
        console.print(f"{where}: all kept from an earlier run (--resume)", soft_wrap=True)
        return
    kernels = report.get("kernels")
    console.print(
        f"{where}{f' ({kept} kept from an earlier run)' if kept else ''}; median per frame: "
        f"read {t['read']:.1f} ms, denoise {t['denoise']:.1f} ms, write {t['write']:.1f} ms"
        + (f"; custom ops: {KERNELS_LABEL.get(kernels, kernels)}" if kernels is not None else "")
        + (f"; conv forms: {report['layout']}" if report.get("layout") else ""),
        soft_wrap=True,
    )


def _jobs(
    inputs: list[str], output: Path, reference: str | None, demo: bool
) -> tuple[list[Job], bool]:
    """The sequences to denoise, and whether they are several (each into OUT/<shot>/)."""
    if demo:
        if inputs or reference:
            raise InputError("--demo takes no INPUT or --reference (it uses its own)")
        from rtdenoise.shipped import sample_sequences

        seqs = sample_sequences()
        if not seqs:
            raise InputError("this installation has no bundled sample sequences for --demo")
        return [Job(s.name, find_frames(s), None, output / s.name) for s in seqs], True
    if not inputs:
        raise InputError("give an INPUT sequence (folder, quoted glob or printf pattern) or --demo")
    shots = group_shots(inputs)
    if len(shots) == 1:
        name = inputs[0] if len(inputs) == 1 else shots[0][0]
        return [Job(name, find_frames(shots[0][1]), reference, output)], False
    if reference is not None:
        raise InputError(
            f"--reference names the references of one shot, got {len(shots)} shots; "
            "put ref_NNNN.exr beside each shot's frames instead"
        )
    return [Job(name, find_frames(specs), None, output / name) for name, specs in shots], True


def _show_layout(value: str | None) -> None:
    """`--show-layout`: print the layout file, to copy and edit, and exit."""
    if value is None:
        return
    with user_errors():
        path = get_layout(value).path
        if path is None:
            raise InputError(f"layout {value!r} has no file")
        print(path.read_text(encoding="utf-8"), end="")
    raise typer.Exit()


@app.command(
    epilog="Layouts: " + _LAYOUT_HELP + ". Motion convention: pixels, previous position = "
    "current + motion, x right, y down. Exit codes: 0 ok, 2 bad input, 1 processing failure."
)
def run(
    inputs: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="INPUT",
            help="Frames: a folder (its `*.exr` except `ref_*`), a quoted glob (`'shots/f_*.exr'`)"
            " or a printf pattern (`shots/f_%04d.exr`). Ordered by the last number in the name. "
            "Several = several shots, each its own sequence (state reset) into `OUT/<shot>/`; "
            "EXR files listed one by one are one shot per folder.",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "-o",
            "--output",
            help="Output folder (required): `OUT/<input name>.exr` (R,G,B); "
            "`OUT/<shot>/<input name>.exr` with several shots.",
        ),
    ] = None,
    model: Annotated[
        str,
        typer.Option(
            "--model",
            "-m",
            help="**none** (pass-through: output = input colour, an I/O diagnostic), "
            "a path to an .onnx model (denoise-export), or a shipped demo: "
            + ", ".join(demo_names())
            + " (README: which is best for what).",
        ),
    ] = DEFAULT_MODEL,
    layout: Annotated[
        str,
        typer.Option(
            "--layout",
            "-l",
            help="Channel layout: a preset (" + ", ".join(LAYOUTS) + ") or a layout file "
            "`my_renderer.toml` (docs/layouts.md; start from `--show-layout blender`).",
        ),
    ] = "canonical",
    channel: Annotated[
        list[str] | None,
        typer.Option(
            "--channel",
            "-c",
            metavar="BUFFER=LAYER",
            help="Override where a buffer comes from (repeatable). LAYER uses LAYER.R/G/B "
            "(or .X/.Y/.Z; one channel for depth; X,Y for motion), with any view-layer prefix; "
            "or list exact channels: motion=mv.X,mv.Y; or 'none' to ignore the buffer. "
            "Buffers: color, color_b, albedo, normal, depth, motion.",
        ),
    ] = None,
    reference: Annotated[
        str | None,
        typer.Option(
            "--reference",
            "-r",
            help="References (folder, glob or printf pattern), matched by frame number. "
            "Default: `ref_NNNN.exr` beside each frame.",
        ),
    ] = None,
    metrics_json: Annotated[
        Path | None,
        typer.Option("--metrics-json", help="Write per-frame and mean metrics and timings here."),
    ] = None,
    preview: Annotated[
        bool, typer.Option("--preview", help="Also write `OUT/<name>.png` (tonemapped, 8-bit).")
    ] = False,
    demo: Annotated[
        bool,
        typer.Option("--demo", help="Run on the bundled sample sequences into `OUT/<sequence>/`."),
    ] = False,
    half: Annotated[
        bool, typer.Option("--half/--float", help="Output EXR as half (default) or 32-bit float.")
    ] = True,
    portable: Annotated[
        bool,
        typer.Option(
            "--portable", help="Run the custom ops' standard-ONNX bodies, not the fast kernels."
        ),
    ] = False,
    threads: Annotated[
        int | None,
        typer.Option(
            "--threads",
            min=1,
            help="Threads of ONNX Runtime and of the fast kernels (numba) (default: all cores); "
            "with --cluster, also the CPUs Ray reserves for each shot (default there: 1).",
        ),
    ] = None,
    overwrite: Annotated[
        bool,
        typer.Option("--overwrite", help="Replace outputs that exist (default: refuse to start)."),
    ] = False,
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Keep the outputs that exist and denoise the other frames, re-running up to "
            "16 frames before each to rebuild the temporal history.",
        ),
    ] = False,
    provider: Annotated[
        list[str] | None,
        typer.Option(
            "--provider",
            "-p",
            metavar="NAME",
            help="ONNX Runtime execution provider, in order of preference (repeatable): cpu "
            "(default), cuda, tensorrt, dml, coreml, openvino or a full name "
            "(`CUDAExecutionProvider`); CPU stays the fallback. CUDA and TensorRT need the "
            "onnxruntime-gpu package, DirectML onnxruntime-directml.",
        ),
    ] = None,
    show_layout: Annotated[
        str | None,
        typer.Option(
            "--show-layout",
            metavar="LAYOUT",
            callback=_show_layout,
            is_eager=True,
            help="Print a layout file (a preset's name or a .toml path) and exit: "
            "`denoise-run --show-layout blender > my_renderer.toml`, then edit.",
        ),
    ] = None,
    version: VersionOption = False,
    online: Annotated[
        bool,
        typer.Option(
            "--online/--no-online",
            help="A model that learns while it runs (e.g. crossreg) takes its update step "
            "(default), or keeps what it learned frozen (its weights; crossreg's gain curve).",
        ),
    ] = True,
    learn_every: Annotated[
        int,
        typer.Option(
            "--learn-every", min=1, help="Online learning: update on every N-th frame only."
        ),
    ] = 1,
    relearn_at_cuts: Annotated[
        bool,
        typer.Option(
            "--relearn-at-cuts",
            help="Online learning: a cut (a gap in the frame numbers, a new shot) also restarts "
            "the learning from the model's initial weights; by default the weights learned so "
            "far carry over (the history restarts either way).",
        ),
    ] = False,
    kernel_size: Annotated[
        int | None,
        typer.Option(
            "--kernel-size",
            help="Run-time kernel size of models that offer one (odd; e.g. demo:affinity, "
            "trained at 13: 7..19 without retraining).",
        ),
    ] = None,
    max_pixels: Annotated[
        int,
        typer.Option(
            "--max-pixels",
            min=1,
            help="Refuse EXR files whose frame has more pixels than this, from the header, "
            f"before decoding (default {DEFAULT_MAX_PIXELS} = 8192x8192).",
        ),
    ] = DEFAULT_MAX_PIXELS,
    cluster: ClusterOption = False,
    cluster_address: ClusterAddressOption = None,
    gpus_per_task: Annotated[
        float,
        typer.Option(
            "--gpus-per-task",
            min=0,
            help="With --cluster: GPUs Ray reserves for each shot (e.g. 1 with `-p cuda`; "
            "0.5 runs two shots per GPU).",
        ),
    ] = 0,
    retries: RetriesOption = DEFAULT_RETRIES,
) -> None:
    """Denoise an EXR frame sequence with a real-time denoiser, frame after frame.

    Reads each frame's canonical buffers (color, albedo, normal, depth, motion, ...)
    through a **layout**, runs the model with its temporal state, and writes
    `OUT/<same name>.exr` atomically (no partial files). With references (`ref_NNNN.exr`
    beside the frames, or --reference) prints PSNR / SSIM / SMAPE / relMSE of the output
    and of the noisy input, and TRMAE over the sequence. NaN/Inf input pixels are
    replaced and reported; out-of-range values are clamped (docs/reliability.md). Existing
    outputs are never replaced unless --overwrite; --resume continues an interrupted run.
    A gap in the frame numbers resets the history. Ctrl-C stops after the frame being
    written, leaving only complete files (exit 130).

    Several shots run one after another, or with --cluster one Ray task each, in parallel
    on this machine or a Ray cluster (docs/cluster.md): a shot that fails is reported by
    name, the others finish, and the exit code is non-zero.

    Metrics: PSNR and SSIM on tau-tonemapped images, tau(x) = (x / (1 + x))^(1/2.4);
    SMAPE and relMSE on linear radiance; the mean PSNR pools the error over all frames.
    In --metrics-json, null means infinite or undefined (e.g. PSNR of identical images).
    """
    out, err = Console(), Console(stderr=True)
    with user_errors():
        if output is None:
            raise InputError("missing option -o/--output (the output folder)")
        overrides = parse_overrides(channel)
        lay = get_layout(layout)
        check_out_dir(output)
        if overwrite and resume:
            raise InputError("--overwrite and --resume exclude each other")
        if metrics_json is not None:
            if metrics_json.is_dir():
                raise InputError(
                    f"{metrics_json}: --metrics-json is a folder, expected a file path"
                )
            check_writable(metrics_json)  # now, not after every frame
            if metrics_json.exists() and not (overwrite or resume):
                raise InputError(
                    f"{metrics_json}: exists; --overwrite replaces it (and existing outputs), "
                    "--resume rewrites it for the resumed run"
                )
        jobs, several = _jobs(list(inputs or []), output, reference, demo)
        cluster = cluster or cluster_address is not None
        if gpus_per_task and not cluster:
            raise InputError("--gpus-per-task is for --cluster (one Ray task per shot)")
        if cluster:
            spec = BackendSpec(
                model,
                portable=portable,
                threads=threads,
                providers=tuple(provider or ()),
                learn=online,
                learn_every=learn_every,
                relearn_at_cuts=relearn_at_cuts,
                options={"kernel_size": kernel_size} if kernel_size is not None else None,
            )
            code = run_cluster(
                jobs,
                spec,
                lay,
                overrides,
                address=cluster_address,
                gpus_per_task=gpus_per_task,
                retries=retries,
                metrics_json=metrics_json,
                options={
                    "half": half,
                    "preview": preview,
                    "overwrite": overwrite,
                    "resume": resume,
                    "max_pixels": max_pixels,
                },
                out=out,
                err=err,
            )
            if code:
                raise typer.Exit(code)
            return
        with kernel_compilation(progress_line(err)):  # numba compiles on first use
            backend = load_backend(
                model,
                portable=portable,
                threads=threads,
                providers=provider,
                learn=online,
                learn_every=learn_every,
                relearn_at_cuts=relearn_at_cuts,
                options={"kernel_size": kernel_size} if kernel_size is not None else None,
            )
            reports = []
            for job in jobs:
                report = run_with_progress(
                    job,
                    backend,
                    lay,
                    overrides,
                    half=half,
                    preview=preview,
                    err=err,
                    overwrite=overwrite,
                    resume=resume,
                    max_pixels=max_pixels,
                )
                report["online"] = online_summary(backend)
                print_report(report, model, out)
                if report["online"]:
                    print_online(report["online"], out)
                reports.append(report)
            if len(reports) > 1:
                print_overall(reports, model, out)
            if metrics_json is not None:
                if several:
                    payload: dict[str, Any] = {
                        "model": model,
                        "layout": lay.name,
                        "sequences": reports,
                    }
                else:
                    payload = {"model": model, "layout": lay.name, **reports[0]}
                write_json(metrics_json, payload)


def progress_line(err: Console) -> Callable[[str], None]:
    """A progress message: above the live bar on a terminal, else a plain stderr line."""
    if err.is_terminal:
        return lambda message: err.print(message, markup=False, highlight=False)
    return plain_line


def run_cluster(
    jobs: list[Job],
    spec: BackendSpec,
    layout: Layout,
    overrides: dict[str, str],
    *,
    address: str | None,
    gpus_per_task: float,
    retries: int,
    metrics_json: Path | None,
    options: dict[str, Any],
    out: Console,
    err: Console,
) -> int:
    """`--cluster`: one Ray task per shot, one progress bar, a table; returns the exit code."""
    if spec.model.strip().lower() != "none":
        from rtdenoise.runtime import resolve_model

        resolve_model(spec.model)  # a typo fails once here, not once per shot
    with user_errors(extra="cluster"):
        from rtdenoise.runtime.sequences.cluster import connect

        started = connect(address)
    try:
        totals = {job.name: len(job.frames) for job in jobs}
        with task_progress(err, totals, "denoise") as (on_progress, on_done):
            outcomes = run_shots(
                jobs,
                spec,
                layout,
                overrides,
                num_gpus=gpus_per_task,
                max_retries=retries,
                on_progress=on_progress,
                on_done=on_done,
                **options,
            )
    finally:
        if started:
            import ray

            ray.shutdown()
    for o in outcomes:
        for message in o.warnings:
            warn(message)
    reports = [o.result for o in outcomes if o.ok]
    print_shots(outcomes, spec.model, out)
    if len(reports) > 1:
        print_overall(reports, spec.model, out)
    if metrics_json is not None:
        failed = [{"name": o.name, "error": o.error, "attempts": o.attempts} for o in outcomes]
        payload = {
            "model": spec.model,
            "layout": layout.name,
            "sequences": reports,
            "failed": [f for f, o in zip(failed, outcomes, strict=True) if not o.ok],
        }
        write_json(metrics_json, payload)
    return report_failures(outcomes, "shot")


def print_shots(outcomes: list[TaskOutcome], model: str, console: Console) -> None:
    """One row per shot: frames, mean metrics of the output (noisy input in brackets), time."""
    table = Table(
        title=f"model {model}, one Ray task per shot (noisy input in brackets)",
        title_justify="left",
    )
    for label, justify in (
        ("shot", "left"),
        ("frames", "right"),
        ("PSNR dB ↑", "right"),
        ("SSIM ↑", "right"),
        ("time s", "right"),
        ("result", "left"),
    ):
        table.add_column(label, justify=justify)
    for o in outcomes:
        tries = f" ({o.attempts} attempts)" if o.attempts > 1 else ""
        if not o.ok:
            table.add_row(o.name, "-", "-", "-", "-", f"[red]failed{tries}[/red]")
            continue
        r = o.result
        mean, inp = r.get("mean"), r.get("input")
        metrics = [
            f"{_format(mean[k], k)} ({_format(inp[k], k)})" if mean and inp else "-"
            for k in ("psnr", "ssim")
        ]
        kept = f", {r['skipped']} kept" if r.get("skipped") else ""
        table.add_row(
            o.name, str(len(r["frames"])), *metrics, f"{o.seconds:.1f}", f"ok{tries}{kept}"
        )
    console.print(table)


def print_online(summary: dict[str, Any], console: Console) -> None:
    if not summary["learn"]:
        console.print("online learning off (--no-online): weights frozen at the model's own")
        return
    every = f" (every {summary['learn_every']} frames)" if summary["learn_every"] > 1 else ""
    console.print(
        f"online learning{every}: {summary.get('step', 0):.0f} update steps in this sequence, "
        f"last frame's loss {summary.get('loss', float('nan')):.4f}"
    )


def print_overall(reports: list[dict[str, Any]], model: str, console: Console) -> None:
    """One line over several sequences: mean PSNR of the output and of the noisy input."""
    scored = [r for r in reports if r.get("mean") and r.get("input")]
    if not scored:
        return
    out_psnr = float(np.mean([r["mean"]["psnr"] for r in scored]))
    in_psnr = float(np.mean([r["input"]["psnr"] for r in scored]))
    console.print(
        f"[bold]{model}[/bold] over {len(scored)} sequences: mean PSNR {out_psnr:.2f} dB "
        f"(noisy input {in_psnr:.2f} dB, {out_psnr - in_psnr:+.2f} dB)"
    )


def main() -> None:
    """Console script entry point."""
    one_line_warnings()
    # A program denoising frame after frame: reuse large blocks instead of fresh mmaps that
    # page-fault on every frame (process-wide, so the CLI decides it, not the library).
    tune_allocator()
    app()


__all__ = [
    "DEFAULT_MODEL",
    "app",
    "main",
    "print_report",
    "print_shots",
    "run_cluster",
    "run_with_progress",
]
