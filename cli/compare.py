"""`denoise-bench compare`: exported models and Open Image Denoise on the same frames."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from .common import parse_size, progress_status, user_errors, warn, write_json

console = Console()
DEFAULT_SIZES = ("320x240", "1280x720", "1920x1080")


def _onnx_source(spec: str) -> str | bytes:
    """An .onnx path or demo:<family> as is; a .pt checkpoint exported in memory (needs torch)."""
    if spec.endswith((".pt", ".pth")):
        from rtdenoise.export.onnx_export import export_model
        from rtdenoise.models.checkpoint import load_checkpoint

        model, _ = load_checkpoint(spec)
        return export_model(model).SerializeToString()
    return spec


def _checkpoint(spec: str) -> str | None:
    """The PyTorch checkpoint behind a model spec: demo:<family>'s shipped .pt, a .pt itself;
    None for an .onnx file (an exported graph has no PyTorch model)."""
    if spec.endswith((".pt", ".pth")):
        return spec
    if spec.startswith("demo:"):
        from rtdenoise.shipped import MODELS_DIR

        path = MODELS_DIR / f"{spec.removeprefix('demo:')}.pt"
        return str(path) if path.is_file() else None
    return None


def _eager(spec: str, device: str):
    """The PyTorch eager contender of a model spec (needs the export extra: torch)."""
    from rtdenoise.runtime.errors import InputError

    checkpoint = _checkpoint(spec)
    if checkpoint is None:
        raise InputError(
            f"--eager: {spec} has no PyTorch checkpoint (give its .pt or demo:<family>)"
        )
    from rtdenoise.export.eager_compare import eager_contender

    return eager_contender(f"{spec} (PyTorch {device})", checkpoint, device)


def _fmt(value: float, digits: int = 1) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _plot(path: Path, result: dict[str, Any], size: list[int]) -> None:
    """PSNR vs ms per frame at `size`, one labelled point per contender (matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        from rtdenoise.runtime.errors import InputError

        raise InputError("--plot needs matplotlib: pip install 'rtdenoise[bench]'") from None
    from rtdenoise.runtime.sequences.atomic import atomic_path

    row = next(r for r in result["speed"] if r["size"] == size)
    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    for name, q in result["quality"].items():  # one colour per contender, named in the legend
        ms = row["summary"][name]["median_ms"]
        lo, hi = row["summary"][name]["min_ms"], row["summary"][name]["max_ms"]
        ax.errorbar(
            ms, q["mean"]["psnr"], xerr=[[ms - lo], [hi - ms]], fmt="o", capsize=3, label=name
        )
    ax.axhline(result["noisy"]["mean"]["psnr"], color="gray", ls="--", lw=1, label="noisy input")
    ax.set_xscale("log")
    ax.set_xlabel(f"ms per frame at {size[1]}x{size[0]} (median, min-max)")
    ax.set_ylabel("PSNR dB (tau-mapped, pooled)")
    ax.set_title(f"quality vs time, {result['machine']}")
    ax.legend(loc="lower right", fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def compare_command(
    models: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="MODEL",
            help="Exported .onnx files, .pt checkpoints (exported in memory) or demo:<family>. "
            "Default: every shipped demo.",
            show_default=False,
        ),
    ] = None,
    oidn: Annotated[
        list[str] | None,
        typer.Option(
            help="OIDN quality to include (repeatable): high, balanced, fast; 'none' for no "
            "OIDN. Default: high and fast. Needs the bench extra (pyoidn).",
        ),
    ] = None,
    size: Annotated[
        list[str] | None,
        typer.Option(help="Frame size WIDTHxHEIGHT (repeatable). Default: 320x240, 720p, 1080p."),
    ] = None,
    repeats: Annotated[
        int,
        typer.Option(
            min=1,
            help="Timed frames per contender at 720p and above; smaller sizes get more, in "
            "proportion to their pixels, up to 4x.",
        ),
    ] = 5,
    sequence: Annotated[
        list[Path] | None,
        typer.Option(
            help="Sequence folder with references for quality (repeatable). "
            "Default: the bundled sample sequences."
        ),
    ] = None,
    portable: Annotated[
        bool, typer.Option("--portable", help="Also time each model on ORT's portable path.")
    ] = False,
    threads: Annotated[
        int | None,
        typer.Option(min=1, help="Threads for ONNX Runtime and the fast kernels (default: all)."),
    ] = None,
    eager: Annotated[
        bool,
        typer.Option(
            "--eager",
            help="Also time each model in PyTorch eager (its deployed form; needs its checkpoint: "
            "demo:<family> or a .pt) on --device. On a CPU the heavy families are slow there: "
            "demo:crossreg at 1080p takes about a minute and 11 GiB per frame on 2 cores.",
        ),
    ] = False,
    device: Annotated[
        str,
        typer.Option(
            help="Torch device of the --eager models and of OIDN: cpu, or cuda[:N] (OIDN then "
            "runs on the GPU through torch tensors). ONNX Runtime stays on its CPU provider.",
        ),
    ] = "cpu",
    json_path: Annotated[
        Path | None, typer.Option("--json", help="Write every number here (JSON).")
    ] = None,
    plot: Annotated[
        Path | None,
        typer.Option(help="Write a PNG of PSNR vs ms per frame (at 720p if timed) here."),
    ] = None,
) -> None:
    """Compare denoisers on the same frames: exported models on ONNX Runtime (fast kernels)
    and Intel Open Image Denoise (RT filter, HDR, albedo + normal).

    Speed: interleaved rounds (A B C A B C ..., every size in every round) after a warm-up
    round, median and min-max of REPEATS frames per size (more for small sizes), and ns per
    pixel; models carry their state (one per size), OIDN is per frame. The sizes warm up
    smallest first; one that would not fit in memory (from the growth of the previous size)
    is left out, with a warning, before its first frame.
    Quality: PSNR (tau-mapped, pooled), SSIM, SMAPE, relMSE (eps 0.01) and TRMAE on sequences
    with references, per sequence in the JSON, their means in the table.
    """
    import platform

    from rtdenoise.runtime.denoiser import Denoiser
    from rtdenoise.runtime.layout import nchwc_block
    from rtdenoise.runtime.sequences import compare
    from rtdenoise.shipped import MODELS_DIR

    with user_errors(extra="bench"):
        sizes = [parse_size(s)[::-1] for s in (size or DEFAULT_SIZES)]  # (H, W)
        qualities = [q for q in (oidn or ["high", "fast"]) if q != "none"]
        specs = models or [f"demo:{p.stem}" for p in sorted(MODELS_DIR.glob("*.onnx"))]
        if device != "cpu":  # checked before any work (needs torch)
            from rtdenoise.models.device import torch_device

            torch_device(device)
        if threads and eager:  # Denoiser(threads=) sets ORT's and numba's own
            import torch

            torch.set_num_threads(threads)
        contenders = []
        for spec in specs:
            source = _onnx_source(spec)
            for fast in (True, False) if portable else (True,):
                label = spec + ("" if fast else " (portable)")

                def remake(source=source, fast=fast) -> Denoiser:
                    return Denoiser(source, fast_kernels=fast, threads=threads, shared_arena=True)

                contenders.append(compare.model_contender(label, remake(), remake))
            if eager:
                contenders.append(_eager(spec, device))
        if device == "cpu":
            contenders += [compare.oidn_contender(q) for q in qualities]
        else:
            from rtdenoise.export.eager_compare import oidn_torch_contender

            contenders += [oidn_torch_contender(q, device) for q in qualities]
        needed = sorted({b for c in contenders for b in c.buffers})
        seqs = compare.load_sequences(list(sequence or []), needed)
        with progress_status(console, "comparing") as say:
            speed, skipped = compare.speed(contenders, sizes, repeats=repeats, progress=say)
            for left_out in skipped:
                warn(left_out["reason"])
            quality = compare.quality(contenders, seqs, progress=say)
            noisy = compare.noisy_quality(seqs)
        machine = f"{platform.machine()}, {__import__('os').cpu_count()} CPUs"
        result = {
            "machine": machine,
            # ORT's CPU conv block here: 16 picks models' AVX-512 conv forms (runtime/layout.py)
            "nchwc_block": nchwc_block(),
            "threads": threads,
            "device": device,
            "repeats": repeats,
            "sequences": [s[0] for s in seqs],
            "speed": speed,
            "skipped_sizes": skipped,
            "quality": quality,
            "noisy": noisy,
        }
        _print(result)
        if json_path is not None:
            write_json(json_path, result)
        if plot is not None:
            timed = [r["size"] for r in speed]
            _plot(plot, result, [720, 1280] if [720, 1280] in timed else timed[-1])


# column label and digits of each score of runtime.sequences.compare.SCORES
SCORE_COLUMNS = {
    "psnr": ("PSNR dB", 2),
    "ssim": ("SSIM", 4),
    "smape": ("SMAPE", 4),
    "relmse": ("relMSE", 4),
    "trmae": ("TRMAE", 4),
}


def _scores(m: dict[str, float]) -> list[str]:
    """The quality columns of one row, in SCORE_COLUMNS' order."""
    return [_fmt(m[k], digits) for k, (_, digits) in SCORE_COLUMNS.items()]


def _print(result: dict[str, Any]) -> None:
    """Two tables: ms per frame (median, min-max) per size; ns per pixel and quality."""
    sizes = [f"{w}x{h}" for h, w in (row["size"] for row in result["speed"])]
    times = Table(title=f"ms per frame, median (min-max); {result['machine']}")
    per_px = Table(title="ns per pixel (median) and quality on the sequences")
    times.add_column("denoiser")
    per_px.add_column("denoiser")
    for label in sizes:
        times.add_column(label, justify="right")
        per_px.add_column(label, justify="right")
    for label, _ in SCORE_COLUMNS.values():
        per_px.add_column(label, justify="right")
    for name, q in result["quality"].items():
        rows = [row["summary"][name] for row in result["speed"]]
        times.add_row(
            name,
            *(f"{_fmt(s['median_ms'])} ({_fmt(s['min_ms'])}-{_fmt(s['max_ms'])})" for s in rows),
        )
        m = q["mean"]
        per_px.add_row(
            name,
            *(_fmt(s["ns_per_pixel"], 0) for s in rows),
            *_scores(m),
        )
    n = result["noisy"]["mean"]
    per_px.add_row(
        "noisy input",
        *[""] * len(sizes),
        *_scores(n),
    )
    console.print(times)
    console.print(per_px)
