"""Per-frame read and write time of `denoise-run --model none`, before vs after, in one run.

Pass-through isolates the I/O path: reading a frame (channels -> buffers, NaN/Inf check)
and writing the output (quantise, EXR, atomic rename). Both versions are installed into
temp folders (`pip install --no-deps --target`): BEFORE from a git revision, AFTER from this
working tree, and run alternately (A B A B ...) on one generated canonical-layout sequence.
Each run's --metrics-json gives the median per-frame `timing_ms` read and write; the table
shows the median over runs of those, and AFTER / BEFORE.

    python benchmarks/frame_io.py --old d69a5de            # 8 frames 1280x720, 7 rounds

Needs git, pip and an environment with rtdenoise's dependencies (its .venv).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CANONICAL = ["R", "G", "B"] + [f"{layer}.{c}" for layer in ("colorB", "albedo") for c in "RGB"]
CANONICAL += [f"normal.{c}" for c in "XYZ"] + ["depth.Z", "motion.X", "motion.Y"]
UNUSED = [f"{layer}.{c}" for layer in ("diffuse", "specular", "emission") for c in "RGB"]
# Runs denoise-run from the installed copy given as the first argument, after checking that
# this copy, not another rtdenoise on the path, is the one imported.
LAUNCH = (
    "import sys, rtdenoise; root = sys.argv.pop(1); "
    "assert rtdenoise.__file__.startswith(root), rtdenoise.__file__; "
    "sys.argv[0] = 'denoise-run'; from rtdenoise.cli.run import main; main()"
)


def make_sequence(folder: Path, frames: int, height: int, width: int, half: bool) -> None:
    """Canonical frames (every canonical buffer plus unused layers), noisy but compressible:
    smooth gradients plus per-pixel noise, like a low-sample render."""
    from rtdenoise.runtime.sequences.exr import write_exr

    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = (np.sin(x / 97) * np.cos(y / 61) + 1.2).astype(np.float32)
    folder.mkdir(parents=True)
    for k in range(1, frames + 1):
        channels = {}
        for i, name in enumerate(CANONICAL + UNUSED):
            noise = rng.exponential(1.0, (height, width)).astype(np.float32)
            channels[name] = base * (0.5 + 0.1 * i) * noise
        write_exr(folder / f"frame_{k:04d}.exr", channels, half=half)


def _pip_target(source: Path, target: Path) -> None:
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "--target",
            str(target),
            str(source),
        ],
        check=True,
        cwd=source,
    )


def install_revision(rev: str, work: Path) -> Path:
    """`git archive REV` installed into work/before; returns the install folder."""
    src = work / "src-before"
    src.mkdir()
    archive = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev],
        check=True,
        capture_output=True,
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    _pip_target(src, work / "before")
    return work / "before"


def install_worktree(work: Path) -> Path:
    """This working tree (tracked and untracked, not ignored files) installed into work/after."""
    src = work / "src-after"
    files = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        check=True,
        capture_output=True,
    ).stdout.split(b"\0")
    for name in filter(None, files):
        path = ROOT / os.fsdecode(name)
        if path.is_file():
            (src / os.fsdecode(name)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, src / os.fsdecode(name))
    _pip_target(src, work / "after")
    return work / "after"


def run_once(install: Path, seq: Path, out: Path, js: Path) -> dict[str, float]:
    """One `denoise-run --model none`; its median per-frame read and write ms."""
    env = {**os.environ, "PYTHONPATH": str(install)}
    proc = subprocess.run(
        [sys.executable, "-c", LAUNCH, str(install), str(seq), "-o", str(out)]
        + ["--model", "none", "--metrics-json", str(js)],
        env=env,
        cwd=js.parent,  # not the repo root: its rtdenoise/ folder would shadow the install
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        raise SystemExit(f"denoise-run from {install} failed:\n{proc.stderr}")
    timing = json.loads(js.read_text())["timing_ms"]
    return {"read": timing["read"], "write": timing["write"]}


def table(results: dict[str, list[dict[str, float]]]) -> str:
    """Markdown: median (min-max) over runs of each run's median per-frame time."""
    lines = [
        "| per frame (median of runs) | before ms | after ms | after / before |",
        "|---|---:|---:|---:|",
    ]
    for key in ("read", "write", "read+write"):
        cells = []
        for label in ("before", "after"):
            values = [
                r["read"] + r["write"] if key == "read+write" else r[key] for r in results[label]
            ]
            cells.append((statistics.median(values), min(values), max(values)))
        (b, b0, b1), (a, a0, a1) = cells
        lines.append(
            f"| {key} | {b:.1f} ({b0:.1f}-{b1:.1f}) | {a:.1f} ({a0:.1f}-{a1:.1f}) | {a / b:.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--old", default=None, help="BEFORE revision (default: merge-base of HEAD and main)"
    )
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    parser.add_argument("--rounds", type=int, default=7, help="timed runs of each version")
    parser.add_argument(
        "--input",
        choices=("half", "float"),
        default="half",
        help="pixel type of the generated input frames",
    )
    args = parser.parse_args()
    old = (
        args.old
        or subprocess.run(
            ["git", "-C", str(ROOT), "merge-base", "HEAD", "main"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    width, height = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory(prefix="frame_io_") as tmp:
        work = Path(tmp)
        installs = {"before": install_revision(old, work), "after": install_worktree(work)}
        seq = work / "seq"
        make_sequence(seq, args.frames, height, width, half=args.input == "half")
        results: dict[str, list[dict[str, float]]] = {"before": [], "after": []}
        for round_ in range(args.rounds + 1):  # round 0 warms the page cache: not counted
            for label in ("before", "after"):  # A B A B ...
                out = work / f"out-{label}"
                shutil.rmtree(out, ignore_errors=True)
                timing = run_once(installs[label], seq, out, work / f"{label}.json")
                if round_:
                    results[label].append(timing)
                    print(
                        f"round {round_} {label}: read {timing['read']:.1f} ms, "
                        f"write {timing['write']:.1f} ms",
                        file=sys.stderr,
                    )
    head = subprocess.run(
        ["git", "-C", str(ROOT), "describe", "--always", "--dirty"],
        capture_output=True,
        text=True,
    ).stdout.strip()
    print(
        f"{datetime.date.today()}, {platform.machine()} {os.cpu_count()} cores, "
        f"Python {platform.python_version()}: denoise-run --model none, {args.frames} frames "
        f"{width}x{height}, {args.input} input ({len(CANONICAL)} canonical + {len(UNUSED)} unused "
        f"channels), half output; before {old[:7]}, after {head}; {args.rounds} runs each, "
        "alternating\n"
    )
    print(table(results))


if __name__ == "__main__":
    main()
