"""`denoise-export`: checkpoint -> one validated ONNX file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from .common import (
    CONTEXT_SETTINGS,
    FamilyModuleOption,
    VersionOption,
    fail,
    load_family_modules,
    one_line_warnings,
    passive_openmp_threads,
    user_errors,
)

app = typer.Typer(add_completion=False, no_args_is_help=True, context_settings=CONTEXT_SETTINGS)
console = Console()


def resolve_checkpoint(spec: str) -> Path:
    """A checkpoint path, or `demo:<family>` for a checkpoint shipped in the package."""
    if spec.startswith("demo:"):
        from rtdenoise.shipped import demo_model

        return demo_model(spec.split(":", 1)[1], ".pt")
    path = Path(spec)
    if not path.is_file():
        raise FileNotFoundError(f"{spec}: no such checkpoint file")
    return path


def check_output(output: Path, overwrite: bool) -> None:
    """Exit 2 naming OUTPUT when it is a folder, or exists without --overwrite."""
    if output.is_dir():
        fail(f"{output}: is a folder; give the .onnx file to write")
    if output.exists() and not overwrite:
        fail(f"{output}: exists; --overwrite replaces it")


@app.command()
def export(
    checkpoint: Annotated[
        str, typer.Argument(help="Checkpoint (.pt from denoise-train) or demo:<family>.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="The .onnx file to write.")],
    frames: Annotated[
        int, typer.Option(help="Frames of the validation sequence (state fed back).")
    ] = 8,
    size: Annotated[int, typer.Option(help="Validation frame size in pixels (square).")] = 64,
    tolerance: Annotated[
        float, typer.Option(help="Max error |ort-torch|/(1+|torch|) accepted on any frame.")
    ] = 1e-4,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", help="Replace OUTPUT if it exists (default: refuse).")
    ] = False,
    family_module: FamilyModuleOption = None,
    version: VersionOption = False,
) -> None:
    """Export a trained denoiser to ONNX and validate it before writing.

    The network becomes standard ONNX ops; the filter stages become custom ops of the
    `rtdenoise` domain, each shipped with a model-local function body so that any stock
    ONNX Runtime runs the file. RepVGG/BatchNorm branches are folded first. The file is
    written only if ONNX Runtime (fast kernels and portable path) matches PyTorch over a
    multi-frame sequence with state fed back. An existing OUTPUT is replaced only with
    --overwrite. Needs the export extra (torch, onnx).
    """
    check_output(output, overwrite)  # before torch loads: a refusal costs nothing
    with user_errors(extra="export"):
        from rtdenoise.export.pipeline import export_checkpoint

        load_family_modules(family_module)
        ckpt = resolve_checkpoint(checkpoint)
        with console.status(f"exporting {ckpt.name} ..."):
            report = export_checkpoint(ckpt, output, frames=frames, size=size, tolerance=tolerance)

    summary = Table(title=f"{report.family} -> {output}", show_header=False)
    summary.add_row("nodes", str(report.nodes))
    custom = ", ".join(f"{k} x{v}" for k, v in sorted(report.custom_nodes.items()))
    summary.add_row("custom nodes", custom or "none")
    summary.add_row("parameters", f"{report.parameters:,}")
    summary.add_row("size", f"{report.size_bytes / 1024:.1f} KiB")
    console.print(summary)
    h, w = report.frame_size
    errors = Table(title=f"validation: {report.source}, {h}x{w}, state fed back")
    errors.add_column("frame", justify="right")
    paths = list(report.validation.errors)
    for path in paths:
        errors.add_column(f"{path} max err", justify="right")
    n = len(next(iter(report.validation.errors.values())))
    for i in range(n):
        errors.add_row(str(i), *(f"{report.validation.errors[p][i]:.2e}" for p in paths))
    console.print(errors)
    console.print(
        f"[green]ok[/green]: max error {report.validation.max_error:.2e} <= {tolerance:g}"
    )


def main() -> None:
    one_line_warnings()
    passive_openmp_threads()
    app()


if __name__ == "__main__":
    main()
