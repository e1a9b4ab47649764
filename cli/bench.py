"""`denoise-bench`: how fast a denoiser runs at a real frame size, every path side by side."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from rtdenoise.runtime.memory import tune_allocator

from .common import (
    CONTEXT_SETTINGS,
    VersionOption,
    fail,
    one_line_warnings,
    parse_size,
    passive_openmp_threads,
    progress_status,
    user_errors,
)
from .compare import compare_command

app = typer.Typer(add_completion=False, no_args_is_help=True, context_settings=CONTEXT_SETTINGS)
console = Console()

LABELS = {
    "torch": "PyTorch eager",
    "torch_deployed": "PyTorch eager (deployed)",
    "ort_fast": "ORT fast",
    "ort_portable": "ORT portable",
    "numba": "numba kernel",
}


FrameSize = Annotated[str, typer.Option(help="Frame size WIDTHxHEIGHT.")]
TimedFrames = Annotated[int, typer.Option(help="Timed frames (after one warm-up frame).")]
JsonOut = Annotated[Path | None, typer.Option("--json", help="Also write JSON here.")]
Threads = Annotated[
    int | None,
    typer.Option(
        min=1,
        help="Threads for ONNX Runtime, the fast kernels (numba) and PyTorch (default: their own).",
    ),
]


@app.callback()
def bench(version: VersionOption = False) -> None:
    """How fast a denoiser runs at a real frame size, every path side by side. Needs the
    bench extra (torch, onnx)."""


@app.command("model")
def bench_model(
    model: Annotated[
        str,
        typer.Argument(help="Checkpoint (.pt), demo:<family>, or a family name (random weights)."),
    ],
    size: FrameSize = "1280x720",
    repeats: TimedFrames = 5,
    threads: Threads = None,
    json_path: JsonOut = None,
) -> None:
    """Time one frame of a denoiser in PyTorch eager (training and deployed form), ONNX
    Runtime with the fast kernels, and ONNX Runtime portable, plus each filter stage the
    model calls. Medians over REPEATS frames measured in one run; speed depends on the
    machine and its load, so compare the columns, not runs on different days.
    """
    with user_errors(extra="bench"):
        w, h = parse_size(size)
        from rtdenoise.export.benchmark import PATHS, benchmark_model
        from rtdenoise.models.checkpoint import load_checkpoint
        from rtdenoise.models.registry import build_model

        from .export import resolve_checkpoint

        if model.startswith("demo:") or model.endswith(".pt"):
            net, _meta = load_checkpoint(resolve_checkpoint(model))
        else:
            net = build_model(model)
        pad = net.pad_multiple
        h, w = -(-h // pad) * pad, -(-w // pad) * pad
        with progress_status(console, "benchmarking") as say:
            result = benchmark_model(net, (h, w), repeats=repeats, threads=threads, progress=say)

    table = Table(title=f"{net.family} at {w}x{h}, median ms per frame ({repeats} frames)")
    table.add_column("stage")
    forms = [*PATHS[:1], "ort_fast", "ort_portable", "numba"]
    for form in forms:
        table.add_column(LABELS[form], justify="right")
    for st in result.stages:
        sh, sw = st["shape"][-2:]  # tensors are N, C, H, W; label WIDTHxHEIGHT like --size
        label = f"{st['op']} {sw}x{sh} x{st['calls_per_frame']}"
        table.add_row(label, *(f"{st['ms'][f]:.1f}" for f in forms))
    table.add_row(
        "whole model",
        *(f"{result.model_ms[f]:.1f}" if f in result.model_ms else "" for f in forms),
    )
    console.print(table)
    console.print(
        f"PyTorch eager deployed form: {result.model_ms['torch_deployed']:.1f} ms; "
        f"ORT fast is {result.model_ms['torch'] / result.model_ms['ort_fast']:.2f}x PyTorch eager"
    )
    if json_path:
        payload = {
            "family": net.family,
            "size": [h, w],
            "repeats": repeats,
            "model_ms": result.model_ms,
            "stages": result.stages,
        }
        json_path.write_text(json.dumps(payload, indent=2))


@app.command("stages")
def bench_stages(
    model: Annotated[
        str,
        typer.Argument(help="demo:<family> (its shipped ONNX) or a checkpoint (.pt, exported)."),
    ],
    size: FrameSize = "1280x720",
    repeats: TimedFrames = 3,
    threads: Threads = None,
    json_path: JsonOut = None,
    portable: Annotated[
        bool,
        typer.Option(
            "--portable/--no-portable",
            help="Also the whole frame in ORT portable (slow at 720p for crossreg).",
        ),
    ] = True,
) -> None:
    """Time each stage of one frame (regression, U-Net, filter, backward + Adam, other) in
    PyTorch eager and ONNX Runtime with the fast kernels (its node profiler), and the whole
    frame in ORT portable, in one run, state fed back. For models that mark their stages
    (crossreg); medians over REPEATS frames."""
    with user_errors(extra="bench"):
        w, h = parse_size(size)
        from rtdenoise.export.onnx_export import export_model
        from rtdenoise.export.stage_bench import STAGES, benchmark_stages
        from rtdenoise.models.checkpoint import load_checkpoint
        from rtdenoise.shipped import demo_model

        from .export import resolve_checkpoint

        net, _meta = load_checkpoint(resolve_checkpoint(model))
        pad = net.pad_multiple
        h, w = -(-h // pad) * pad, -(-w // pad) * pad
        with progress_status(console, "benchmarking") as say:
            if model.startswith("demo:"):
                onnx_bytes = demo_model(model.split(":", 1)[1], ".onnx").read_bytes()
            else:
                say("exporting")
                onnx_bytes = export_model(net).SerializeToString()
            result = benchmark_stages(
                net,
                onnx_bytes,
                (h, w),
                repeats=repeats,
                threads=threads,
                progress=say,
                portable=portable,
            )
    table = Table(title=f"{net.family} at {w}x{h}, median ms per frame ({repeats} frames)")
    table.add_column("stage")
    for path in result:
        table.add_column(LABELS[path], justify="right")
    for stage in STAGES:
        cells = [result[p]["stages"].get(stage) for p in result]
        table.add_row(stage, *("" if c is None else f"{c:.0f}" for c in cells))
    table.add_row("whole frame", *(f"{result[p]['total']:.0f}" for p in result))
    console.print(table)
    if json_path:
        payload = {"family": net.family, "size": [h, w], "repeats": repeats, "paths": result}
        json_path.write_text(json.dumps(payload, indent=2))


@app.command("op")
def bench_one_op(
    op: Annotated[str, typer.Argument(help="Custom op name, e.g. KernelApply.")],
    size: Annotated[str, typer.Option(help="Image size WIDTHxHEIGHT.")] = "1280x720",
    channels: Annotated[int, typer.Option(help="Image channels.")] = 3,
    attr: Annotated[
        list[str] | None,
        typer.Option("--attr", help="Op attribute NAME=INT (repeatable); default: the op's own."),
    ] = None,
    repeats: Annotated[int, typer.Option(help="Timed calls (after one warm-up call).")] = 5,
    threads: Threads = None,
) -> None:
    """Time one filter stage in its forms: numba kernel called directly, ORT with the fast
    kernel, ORT running the portable function body, PyTorch eager. Medians, one run.
    E.g. `denoise-bench op WeightSharingFilter --attr size_min=13 --attr count=1`."""
    with user_errors(extra="bench"):
        w, h = parse_size(size)
        from rtdenoise.export.op_bench import bench_op
        from rtdenoise.ops import SPECS

        if op not in SPECS:
            fail(f"unknown op {op!r}; known: {sorted(SPECS)}")
        attrs = dict(SPECS[op].default_attrs)
        for item in attr or []:
            name, sep, value = item.partition("=")
            if not sep or name not in attrs or not value.lstrip("-").isdigit():
                fail(f"--attr {item!r}: expected NAME=INT with NAME in {sorted(attrs)}")
            attrs[name] = int(value)
        with progress_status(console, "benchmarking") as say:
            say(op)
            result = bench_op(
                op, (1, channels, h, w), repeats=repeats, attrs=attrs, threads=threads or 0
            )
    table = Table(title=f"{op} {attrs} at {w}x{h}, {channels} channels, median ms per call")
    for form in result["ms"]:
        table.add_column(LABELS.get(form, form), justify="right")
    table.add_row(*(f"{ms:.1f}" for ms in result["ms"].values()))
    console.print(table)
    worst = max(result["max_abs_diff"].values())
    console.print(f"largest difference from PyTorch: {worst:.2e}")


app.command("compare")(compare_command)


def main() -> None:
    one_line_warnings()
    passive_openmp_threads()
    tune_allocator()  # as denoise-run does: measure what it runs
    app()


if __name__ == "__main__":
    main()
