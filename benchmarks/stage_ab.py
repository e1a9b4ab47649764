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
import contextlib
import json
import os
import statistics
import tempfile
import time
from dataclasses import dataclass, field

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402

from rtdenoise.export.learning_branch import all_nodes  # noqa: E402
from rtdenoise.export.stage_bench import (  # noqa: E402
    STAGES,
    node_ms_per_run,
    node_stages,
    profiled_stage,
)
from rtdenoise.runtime import bridge  # noqa: E402
from rtdenoise.runtime.contract import RESET, contract_from_session  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402
from rtdenoise.runtime.session import ALLOW_SPINNING, kernel_thread_count  # noqa: E402
from rtdenoise.runtime.static_check import custom_op_types  # noqa: E402
from rtdenoise.shipped import demo_model  # noqa: E402


@dataclass
class Side:
    """One file's session, its node -> stage map, its state and its frame times."""

    name: str
    session: ort.InferenceSession
    chosen: str | None
    stages: dict[str, str | None]
    contract: object
    state: dict[str, np.ndarray] = field(default_factory=dict)
    walls: list[float] = field(default_factory=list)


def open_side(name: str, source: str, threads: int | None) -> Side:
    """A profiled fast-path session of `source` (a path or demo:<family>)."""
    path = demo_model(source.split(":", 1)[1], ".onnx") if source.startswith("demo:") else source
    data = open(path, "rb").read()
    proto = onnx.load_from_string(data)
    for i, node in enumerate(all_nodes(proto.graph)):  # the profiler reports nodes by name
        node.name = node.name or f"node_{i}"
    so = ort.SessionOptions()
    if threads:
        so.intra_op_num_threads = threads
    chosen = bridge.register_fast_kernels(so, None, custom_op_types(data))
    so.add_session_config_entry(ALLOW_SPINNING, "0")
    so.enable_profiling = True
    so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), name)
    session = ort.InferenceSession(proto.SerializeToString(), so, ["CPUExecutionProvider"])
    contract = contract_from_session(session)
    return Side(name, session, chosen, node_stages(proto, contract.online), contract)


def run_frame(side: Side, frame: dict, first: bool, threads: int | None) -> None:
    """One learning frame (reset on the first), its state fed back, its wall time kept."""
    contract = side.contract
    h, w = frame[contract.buffer_names[0]].shape[-2:]
    if first:
        side.state = {s.name: np.zeros(s.shape(h, w), np.float32) for s in contract.state}
    feed = {name: frame[name][None] for name in contract.buffer_names}
    feed[RESET] = np.array(1.0 if first else 0.0, np.float32)
    feed.update({s.input_name: side.state[s.name] for s in contract.state})
    team = kernel_thread_count((h, w), threads)
    context = bridge.kernel_threads(side.chosen, team) if side.chosen else contextlib.nullcontext()
    t0 = time.perf_counter()
    with context:
        outs = side.session.run(None, feed)
    side.walls.append((time.perf_counter() - t0) * 1e3)
    named = dict(zip([o.name for o in side.session.get_outputs()], outs, strict=True))
    side.state = {s.name: named[s.output_name] for s in contract.state}


def stage_times(side: Side, warmup: int) -> dict[str, list[float]]:
    """{stage or "whole frame": ms of each timed frame}."""
    runs = node_ms_per_run(
        side.session.end_profiling(), lambda node, _op: profiled_stage(node, side.stages)
    )[warmup:]
    times = {s: [run.get(s, 0.0) for run in runs] for s in STAGES}
    times["whole frame"] = side.walls[warmup:]
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
        sides[0].contract.buffer_names, args.warmup + args.frames, h, w, seed=0
    )
    for k, frame in enumerate(frames):
        for side in sides if k % 2 == 0 else sides[::-1]:
            run_frame(side, frame, k == 0, args.threads)
    a, b = (stage_times(s, args.warmup) for s in sides)
    print(f"{w}x{h}, {args.frames} learning frames after {args.warmup} warm-up, "
          f"threads {args.threads}, bridges {sides[0].chosen} / {sides[1].chosen}\n")  # fmt: skip
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
