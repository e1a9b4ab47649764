"""Two builds of the C++ library rtdenoise_ops (e.g. before and after a kernel change), op by
op, interleaved in one process: each op alone in an ONNX model (no function body), one ORT
session per library file, the op's example inputs at each size, A B A B ... after a warm-up
call of each. Prints one markdown row per op and size: median (min-max) wall ms of each side,
the ratio A / B, the same ratio of the process's CPU time per call (all its threads: on a
loaded machine a call waits for a core, and its CPU time moves less than its wall time), and
the largest relative difference of B's outputs from A's.

    cp runtime/bridge/librtdenoise_ops.so /tmp/before.so      # before the change
    ... rebuild ...
    python benchmarks/native_ops_ab.py --lib before=/tmp/before.so \\
        --lib after=runtime/bridge/librtdenoise_ops.so --op CrossRegression --size 1280x720
    python benchmarks/native_ops_ab.py ... --op TemporalAccumulation --attr per_tap=3

Both files speak to ORT alone (each session registers its own); their thread count is each
library's default (every core, or RTDENOISE_OPS_THREADS).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np
import onnxruntime as ort

from rtdenoise.export import ops as eops
from rtdenoise.ops import get_spec


def session(op: str, attrs: dict, lib: str) -> ort.InferenceSession:
    so = ort.SessionOptions()
    so.register_custom_ops_library(os.path.realpath(lib))
    model = eops.single_op_model(op, None, attrs, with_function=False)
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lib", action="append", required=True, help="NAME=PATH (two)")
    ap.add_argument("--op", action="append", required=True)
    ap.add_argument("--size", action="append", default=None, help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--pause", type=float, default=0.1, help="seconds after each call")
    ap.add_argument(
        "--attr", action="append", default=[], help="NAME=INT: an op attribute (repeatable)"
    )
    args = ap.parse_args(argv)
    libs = [tuple(s.split("=", 1)) for s in args.lib]
    if len(libs) != 2:
        ap.error("--lib twice: NAME=PATH")
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}, {os.cpu_count()} CPUs")
    print(f"# {' '.join(sys.argv)}")
    (na, _), (nb, _) = libs
    print(f"\n| op | size | {na} ms | {nb} ms | {na} / {nb} | CPU {na} / {nb} | max rel diff |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for op in args.op:
        spec = get_spec(op)
        attrs = dict(spec.default_attrs)
        attrs.update({k: int(v) for k, v in (a.split("=", 1) for a in args.attr)})
        for size in args.size or ["1280x720"]:
            w, h = (int(v) for v in size.split("x"))
            inputs = spec.example_inputs((1, 3, h, w), attrs, np.random.default_rng(0))
            feed = dict(zip(spec.input_names, inputs, strict=True))
            sessions = [session(op, attrs, path) for _, path in libs]
            outs = [s.run(None, feed) for s in sessions]  # warm-up, and the outputs compared
            diff = max(
                float(np.abs(a - b).max() / max(1.0, float(np.abs(a).max())))
                for a, b in zip(*outs, strict=True)
            )
            times: list[list[float]] = [[], []]
            cpu: list[list[float]] = [[], []]
            for _ in range(args.rounds):
                for k, s in enumerate(sessions):
                    t0, c0 = time.perf_counter(), time.process_time()
                    s.run(None, feed)
                    times[k].append((time.perf_counter() - t0) * 1e3)
                    cpu[k].append((time.process_time() - c0) * 1e3)
                    time.sleep(args.pause)
            ma, mb = (statistics.median(t) for t in times)
            ca, cb = (statistics.median(t) for t in cpu)
            cells = [f"{statistics.median(t):.1f} ({min(t):.1f}-{max(t):.1f})" for t in times]
            ratios = f"{ma / mb:.2f} | {ca / cb:.2f}"
            row = f"| {op} | {size} | {cells[0]} | {cells[1]} | {ratios} | {diff:.1e} |"
            print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
