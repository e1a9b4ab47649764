"""`denoise-run`: denoise an EXR frame sequence with a model, frame after frame.

Reads a sequence (folder, quoted glob or printf pattern), maps its channels to the
canonical buffers through a layout, runs a backend (`none` = pass-through, an .onnx
file or `demo:<family>`), writes OUT/<same name>.exr (R,G,B), and scores the output
and the noisy input against references when there are any.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from rtdenoise.cli.common import quiet_native_output, user_errors, warn, write_json
from rtdenoise.runtime.backend import Backend, load_backend
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.layouts import LAYOUTS, Layout, get_layout, parse_overrides
from rtdenoise.runtime.memory import tune_allocator
from rtdenoise.runtime.metrics import SequenceMetrics
from rtdenoise.runtime.preview import write_png
from rtdenoise.runtime.samples import sample_features_of
from rtdenoise.runtime.sequence import (
    as_written,
    find_frames,
    match_references,
    read_frame,
    read_reference,
    scan_reference,
    scan_sequence,
    write_output,
)

# The model used when --model is not given: the shipped AFN demo (Lee24).
DEFAULT_MODEL = "demo:afn"
METRIC_KEYS = ("psnr", "ssim", "smape", "relmse")
TABLE_MAX_FRAMES = 12  # per-frame rows up to this many frames, else only the mean
MAX_WARNINGS = 10

_LAYOUT_HELP = "; ".join(f"**{name}**: {lay.description}" for name, lay in LAYOUTS.items())

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    rich_markup_mode="markdown",
    context_settings={"help_option_names": ["-h", "--help"]},
)


@dataclass
class Job:
    """One sequence to denoise."""

    name: str
    frames: list[Path]
    reference: str | None  # reference spec, None = ref_NNNN.exr beside each frame
    out_dir: Path


def _check_out_dir(out_dir: Path) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: output folder is a file")


def _plan_outputs(job: Job, references: list[Path | None], preview: bool) -> list[Path]:
    """OUT/<input name> for every frame; refuse duplicates and overwriting an input."""
    outputs = [job.out_dir / p.name for p in job.frames]
    seen: dict[Path, Path] = {}
    inputs = {p.resolve() for p in job.frames} | {r.resolve() for r in references if r}
    for src, out in zip(job.frames, outputs, strict=True):
        if out in seen:
            raise InputError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
        targets = [out] + ([out.with_suffix(".png")] if preview else [])
        for t in targets:
            if t.resolve() in inputs:
                raise InputError(f"{t}: writing the output would overwrite an input file")
    return outputs


def _format(value: float | None, key: str) -> str:
    if value is None or not np.isfinite(value):
        return "inf" if value is not None and value > 0 else "-"
    return f"{value:.2f}" if key == "psnr" else f"{value:.4f}"


def run_sequence(
    job: Job,
    backend: Backend,
    layout: Layout,
    overrides: dict[str, str],
    *,
    half: bool = True,
    preview: bool = False,
    err: Console | None = None,
) -> dict[str, Any]:
    """Denoise one sequence; returns its report (the metrics JSON of one sequence)."""
    err = err or Console(stderr=True)
    _check_out_dir(job.out_dir)
    with quiet_native_output():
        size = scan_sequence(job.frames, layout, overrides)
    references = match_references(job.frames, job.reference)
    if job.reference is not None and not any(references):
        raise InputError(f"{job.reference}: no reference matches the frame numbers of {job.name}")
    missing_refs = sum(r is None for r in references)
    if any(references) and missing_refs:
        warn(f"{job.name}: {missing_refs} of {len(job.frames)} frames have no reference")
    with quiet_native_output():
        for ref in references:
            if ref is not None:
                scan_reference(ref, layout, expect_size=size)
    outputs = _plan_outputs(job, references, preview)
    required = tuple(getattr(backend, "required_buffers", ()) or ())
    config = getattr(backend, "config", {})
    features = sample_features_of(config) if "samples" in required else None  # per-sample input

    scored_out, scored_in = SequenceMetrics(), SequenceMetrics()
    rows: list[dict[str, Any]] = []
    times: dict[str, list[float]] = {"read": [], "denoise": [], "write": []}
    warnings = 0
    backend.reset()
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
        previous_scored = False
        for i, (path, ref, out_path) in enumerate(
            zip(job.frames, references, outputs, strict=True)
        ):
            t0 = time.perf_counter()
            with quiet_native_output():
                frame = read_frame(path, layout, overrides, size, i, features)
            if i == 0:
                lacking = [b for b in required if b not in frame.buffers]
                if lacking:
                    raise InputError(
                        f"{path}: the model needs buffer {', '.join(map(repr, lacking))}, which "
                        f"layout {layout.name} did not find (use --channel BUFFER=LAYER)"
                    )
            t1 = time.perf_counter()
            out = np.asarray(backend.process(frame.buffers), dtype=np.float32)
            if out.ndim == 4 and out.shape[0] == 1:
                out = out[0]
            if out.shape != (3, *size):
                raise RuntimeError(
                    f"{path}: the model returned shape {out.shape}, not (3, *{size})"
                )
            bad_out = int((~np.isfinite(out)).any(axis=0).sum())
            if bad_out:
                out = np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
            t2 = time.perf_counter()
            write_output(out_path, out, half=half)
            if preview:
                write_png(out_path.with_suffix(".png"), out)
            t3 = time.perf_counter()
            for key, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2), strict=True):
                times[key].append(dt * 1e3)

            if frame.nonfinite or bad_out:
                warnings += 1
                if warnings <= MAX_WARNINGS:
                    parts = []
                    if frame.nonfinite:
                        parts.append(
                            f"{frame.nonfinite} pixels with NaN/Inf in "
                            f"{', '.join(frame.nonfinite_buffers)} replaced by 0"
                        )
                    if bad_out:
                        parts.append(f"{bad_out} non-finite output pixels replaced by 0")
                    warn(f"{path}: " + "; ".join(parts))
            row: dict[str, Any] = {
                "index": frame.index,
                "file": str(path),
                "output": str(out_path),
                "reference": str(ref) if ref else None,
                "nonfinite": frame.nonfinite,
            }
            if ref is not None:
                with quiet_native_output():
                    target = read_reference(ref, layout, expect_size=size)
                # Score what was written: the half-float file when --half.
                written = as_written(out, half)
                row.update(scored_out.add(written, target, consecutive=previous_scored))
                row["input"] = scored_in.add(
                    frame.buffers["color"], target, consecutive=previous_scored
                )
            else:
                row.update(dict.fromkeys(METRIC_KEYS))
                row["input"] = None
            previous_scored = ref is not None
            rows.append(row)
            progress.advance(task)
            progress.refresh()
    if warnings > MAX_WARNINGS:
        warn(f"{job.name}: {warnings - MAX_WARNINGS} more frames had NaN/Inf values")

    out_summary, in_summary = scored_out.summary(), scored_in.summary()
    return {
        "name": job.name,
        "size": list(size),
        "frames": rows,
        "mean": {k: out_summary[k] for k in METRIC_KEYS} if out_summary else None,
        "trmae": out_summary.get("trmae"),
        "input": in_summary or None,
        "nonfinite": sum(r["nonfinite"] for r in rows),
        "timing_ms": {k: statistics.median(v) if v else None for k, v in times.items()},
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
    console.print(
        f"{len(report['frames'])} frames {report['size'][1]}x{report['size'][0]} -> "
        f"{Path(report['frames'][0]['output']).parent}; median per frame: read {t['read']:.1f} ms,"
        f" denoise {t['denoise']:.1f} ms, write {t['write']:.1f} ms",
        soft_wrap=True,
    )


def _jobs(
    inputs: list[str], output: Path, reference: str | None, demo: bool
) -> tuple[list[Job], bool]:
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
    frames = find_frames(inputs)
    name = inputs[0] if len(inputs) == 1 else f"{len(frames)} frames"
    return [Job(name, frames, reference, output)], False


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
            " or a printf pattern (`shots/f_%04d.exr`). Ordered by the last number in the name.",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None,
        typer.Option(
            "-o", "--output", help="Output folder (required): `OUT/<input name>.exr` (R,G,B)."
        ),
    ] = None,
    model: Annotated[
        str,
        typer.Option(
            "--model",
            "-m",
            help="**none** (pass-through: output = input colour, an I/O diagnostic), "
            "a path to an .onnx model (denoise-export), or `demo:<family>`.",
        ),
    ] = DEFAULT_MODEL,
    layout: Annotated[
        str,
        typer.Option("--layout", "-l", help="Channel layout: " + ", ".join(LAYOUTS) + "."),
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
        int | None, typer.Option("--threads", min=1, help="ONNX Runtime intra-op threads.")
    ] = None,
    kernel_size: Annotated[
        int | None,
        typer.Option(
            "--kernel-size",
            help="Run-time kernel size of models that offer one (odd; e.g. demo:affinity, "
            "trained at 13: 7..19 without retraining).",
        ),
    ] = None,
) -> None:
    """Denoise an EXR frame sequence with a real-time denoiser, frame after frame.

    Reads each frame's canonical buffers (color, albedo, normal, depth, motion, ...)
    through a **layout**, runs the model with its temporal state, and writes
    `OUT/<same name>.exr` atomically (no partial files). With references (`ref_NNNN.exr`
    beside the frames, or --reference) prints PSNR / SSIM / SMAPE / relMSE of the output
    and of the noisy input, and TRMAE over the sequence. NaN/Inf input pixels are
    replaced by 0 and reported.

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
        _check_out_dir(output)
        if metrics_json is not None and metrics_json.is_dir():
            raise InputError(f"{metrics_json}: --metrics-json is a folder, expected a file path")
        jobs, is_demo = _jobs(list(inputs or []), output, reference, demo)
        options = {"kernel_size": kernel_size} if kernel_size is not None else None
        backend = load_backend(model, portable=portable, threads=threads, options=options)
        reports = []
        for job in jobs:
            report = run_sequence(job, backend, lay, overrides, half=half, preview=preview, err=err)
            print_report(report, model, out)
            reports.append(report)
        if len(reports) > 1:
            print_overall(reports, model, out)
        if metrics_json is not None:
            if is_demo:
                payload: dict[str, Any] = {"model": model, "sequences": reports}
            else:
                payload = {"model": model, "layout": lay.name, **reports[0]}
            write_json(metrics_json, payload)


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
    # A program denoising frame after frame: reuse large blocks instead of fresh mmaps that
    # page-fault on every frame (process-wide, so the CLI decides it, not the library).
    tune_allocator()
    app()


__all__ = ["DEFAULT_MODEL", "Job", "app", "main", "print_report", "run_sequence"]
