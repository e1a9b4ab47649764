"""A frozen frame vs a learning frame of an online model (demo:crossreg), before vs after a
graph change: every (model, mode) a Denoiser of its own with its state fed back, all timed in
the same interleaved rounds (one frame each per round, 100 ms pause after each frame as
`denoise-bench compare` does), after warm-up rounds; medians per size.

    python benchmarks/frozen_frames.py before=main.onnx after=demo:crossreg \\
        --inference-only after --size 256x256 --size 1280x720 --frames 5

Modes: `learn` (an update step on every frame), `frozen` (`learn=False`: what `--no-online`
and the frames `--learn-every` skips run). `--inference-only LABEL` adds LABEL's graph with
its learning `If` replaced by its else-branch (the learned states passed through): what a
second, inference-only graph in the same file would run on a frozen frame.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts

import onnx  # noqa: E402

from rtdenoise.runtime.denoiser import Denoiser  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402
from rtdenoise.runtime.session import resolve_model  # noqa: E402

SETTLE_S = 0.1


def inference_only(model: str) -> bytes:
    """`model` with its learning If (export/learning_branch.py) replaced by the else-branch."""
    proto = onnx.load(str(resolve_model(model)))
    nodes = []
    for node in proto.graph.node:
        if node.op_type != "If":
            nodes.append(node)
            continue
        branch = next(a.g for a in node.attribute if a.name == "else_branch")
        for inner, out in zip(branch.output, node.output, strict=True):
            (ident,) = [n for n in branch.node if inner.name in n.output]
            nodes.append(onnx.helper.make_node("Identity", list(ident.input), [out]))
    del proto.graph.node[:]
    proto.graph.node.extend(nodes)
    return proto.SerializeToString()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("models", nargs="+", help="LABEL=MODEL (a path or demo:<family>)")
    ap.add_argument("--inference-only", action="append", default=[], metavar="LABEL")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--frames", type=int, default=5, help="timed frames per contender and size")
    ap.add_argument("--warmup", type=int, default=2, help="untimed rounds first")
    args = ap.parse_args(argv)
    tune_allocator()
    sources = dict(m.split("=", 1) for m in args.models)
    contenders: dict[str, tuple[object, bool]] = {}
    for label, model in sources.items():
        contenders[f"{label} learn"] = (model, True)
        contenders[f"{label} frozen"] = (model, False)
    for label in args.inference_only:
        contenders[f"{label} inference-only frozen"] = (inference_only(sources[label]), False)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}, {os.cpu_count()} CPUs")
    print(f"# {' '.join(sys.argv)}")
    sizes = args.size or ["256x256", "1280x720"]
    dens = {
        name: Denoiser(m, learn=learn, shared_arena=True) for name, (m, learn) in contenders.items()
    }
    results: dict[tuple[str, str], list[float]] = {}
    for size in sizes:
        w, h = (int(v) for v in size.split("x"))
        names = next(iter(dens.values())).required_buffers
        frames = synthetic_frames(names, 4, h, w)
        for r in range(args.warmup + args.frames):
            for name, den in dens.items():
                t0 = time.perf_counter()
                den.process(frames[r % len(frames)], reset=r == 0)
                ms = (time.perf_counter() - t0) * 1e3
                if r >= args.warmup:
                    results.setdefault((name, size), []).append(ms)
                time.sleep(SETTLE_S)
    print(f"\n| contender | {' | '.join(f'{s} ms median (min-max)' for s in sizes)} |")
    print(f"|---|{'---:|' * len(sizes)}")
    for name in dens:
        cells = []
        for size in sizes:
            t = results[(name, size)]
            cells.append(f"{statistics.median(t):.1f} ({min(t):.1f}-{max(t):.1f})")
        print(f"| {name} | {' | '.join(cells)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
