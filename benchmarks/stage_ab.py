"""Stage timings of two ONNX files of an online model (e.g. demo:crossreg before and after a
re-export), interleaved in one process: where a learning frame's time goes, side by side.

Each side is one ONNX Runtime session on the fast path, as `Denoiser` opens it (the bridge it
picks for the file's custom ops: the C++ library where it holds them all; idle ORT workers
sleep while a kernel runs) with ORT's node profiler on. Every round runs one learning frame of
each side on the same synthetic frame (the order alternating per round: A B, B A, ...), each
side carrying its own state; the warm-up rounds are dropped. Each profiled node is counted in
its stage as `denoise-bench stages` counts it (export/stage_bench.py: regression, unet,
filter, backward + adam, other; ORT's renamed and inserted nodes included). Prints a markdown
table: median (min-max) ms per stage and per whole frame (wall time of `run`) of each side,
and B / A of the medians.

    python benchmarks/stage_ab.py before=main_crossreg.onnx after=demo:crossreg \\
        --size 1280x720 --frames 3 --warmup 1 --threads 2
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
from dataclasses import dataclass

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from rtdenoise.export.stage_bench import STAGES, ProfiledRun, profiled_run  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402
from rtdenoise.shipped import demo_model  # noqa: E402


@dataclass
class Side:
    """One file's name and its profiled run."""

    name: str
    run: ProfiledRun


def open_side(name: str, source: str, threads: int | None) -> Side:
    """A profiled fast-path session of `source` (a path or demo:<family>)."""
    path = demo_model(source.split(":", 1)[1], ".onnx") if source.startswith("demo:") else source
    with open(path, "rb") as fh:
        return Side(name, profiled_run(fh.read(), True, threads, prefix=name))


def stage_times(side: Side, warmup: int) -> dict[str, list[float]]:
    """{stage or "whole frame": ms of each timed frame}."""
    runs = side.run.stage_ms()[warmup:]
    times = {s: [run.get(s, 0.0) for run in runs] for s in STAGES}
    times["whole frame"] = side.run.walls[warmup:]
    return times


def cell(values: list[float]) -> str:
    return f"{statistics.median(values):.1f} ({min(values):.1f}-{max(values):.1f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("sides", nargs=2, help="NAME=FILE.onnx or NAME=demo:<family>")
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    parser.add_argument("--frames", type=int, default=3, help="timed rounds")
    parser.add_argument("--warmup", type=int, default=1, help="rounds dropped")
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--json", default=None, help="write the per-frame times here")
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    sides = [open_side(*s.split("=", 1), args.threads) for s in args.sides]
    pad = 4  # crossreg's pad multiple; synthetic frames of a padded size
    h, w = -(-h // pad) * pad, -(-w // pad) * pad
    frames = synthetic_frames(
        sides[0].run.contract.buffer_names, args.warmup + args.frames, h, w, seed=0
    )
    for k, frame in enumerate(frames):
        for side in sides if k % 2 == 0 else sides[::-1]:
            side.run.frame(frame, k == 0, args.threads)
    a, b = (stage_times(s, args.warmup) for s in sides)
    bridges = " / ".join(str(s.run.chosen) for s in sides)
    print(f"{w}x{h}, {args.frames} learning frames after {args.warmup} warm-up, "
          f"threads {args.threads}, bridges {bridges}\n")  # fmt: skip
    print(
        f"| stage | {sides[0].name} ms | {sides[1].name} ms | {sides[1].name} / {sides[0].name} |"
    )
    print("|---|---:|---:|---:|")
    for stage in (*STAGES, "whole frame"):
        ma, mb = statistics.median(a[stage]), statistics.median(b[stage])
        ratio = f"{mb / ma:.2f}" if ma > 0 else "-"
        print(f"| {stage} | {cell(a[stage])} | {cell(b[stage])} | {ratio} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                {"size": [h, w], "sides": {s.name: t for s, t in zip(sides, (a, b), strict=True)}},
                fh,
            )


if __name__ == "__main__":
    main()
