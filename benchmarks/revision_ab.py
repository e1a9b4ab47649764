"""Whole frames of two installs of rtdenoise (e.g. before and after a change), interleaved.

Each side is a worker process with its own `PYTHONPATH` (an install of some revision, made with
`pip install --no-deps --no-build-isolation --target DIR <checkout>`; `current` is this
environment's). The parent asks the workers for one frame each in turn (A B A B ..., 100 ms
pause after each frame, as `denoise-bench compare` does), after a warm-up frame; every worker
runs `Denoiser(model)` with the fast kernels on the same synthetic frames, its state carried,
and times `process` itself. Prints one markdown row per model and size: median (min-max) ms
per frame of each side, the ratio, and the largest output difference over the first frames.

    git worktree add /tmp/before 76609a0
    pip install --no-deps --no-build-isolation --target /tmp/before-site /tmp/before
    python benchmarks/revision_ab.py --side before=/tmp/before-site --side after=current \\
        --model demo:afn --size 1280x720 --size 320x240 --rounds 15
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

WORKER = r"""
import json, os, sys, time
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import numpy as np
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.memory import tune_allocator
try:
    from rtdenoise.runtime.sequences.synthetic import synthetic_frames
except ImportError:  # a revision before runtime/ had its sequence wing
    from rtdenoise.runtime.synthetic import synthetic_frames
tune_allocator()
den = frames = None
for line in sys.stdin:
    cmd = json.loads(line)
    if cmd["op"] == "load":
        den = Denoiser(cmd["model"])
        frames = synthetic_frames(den.required_buffers, 4, cmd["h"], cmd["w"])
        reply = {"ok": True}
    else:
        t0 = time.perf_counter()
        out = den.process(frames[cmd["i"] % len(frames)])
        reply = {"ms": (time.perf_counter() - t0) * 1e3}
        if cmd.get("save"):
            np.save(cmd["save"], out)
    print(json.dumps(reply), flush=True)
"""


class Worker:
    """One side: a Python process running `WORKER` with its own import path."""

    def __init__(self, path: str) -> None:
        env = dict(os.environ)
        if path != "current":
            env["PYTHONPATH"] = os.path.abspath(path)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", WORKER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
            text=True,
            # `python -c` puts the working directory first on the import path: run from a
            # checkout's root, every side would import that checkout's rtdenoise
            cwd=tempfile.gettempdir(),
        )

    def ask(self, **cmd) -> dict:
        self.proc.stdin.write(json.dumps(cmd) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"worker exited (code {self.proc.wait()})")
        return json.loads(line)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--side", action="append", required=True, help="NAME=DIR or NAME=current")
    ap.add_argument("--model", action="append", help="demo:<family> or .onnx (repeatable)")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--pause", type=float, default=0.1, help="seconds after each frame")
    args = ap.parse_args(argv)
    sides = [s.split("=", 1) for s in args.side]
    workers = [Worker(path) for _, path in sides]
    names = [name for name, _ in sides]
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}")
    print(f"# {' '.join(sys.argv)}")
    print(f"| model | size | frames | {' | '.join(names)} | ratio | max diff |")
    print("|---|---|---:|" + "---:|" * (len(names) + 2))
    try:
        for model in args.model or ["demo:afn"]:
            for size in args.size or ["1280x720"]:
                w, h = (int(v) for v in size.split("x"))
                outs = []
                for k, worker in enumerate(workers):
                    target = model if model.startswith("demo:") else os.path.abspath(model)
                    worker.ask(op="load", model=target, h=h, w=w)
                    path = f"/tmp/revision_ab_{os.getpid()}_{k}.npy"
                    worker.ask(op="frame", i=0, save=path)  # warm-up, output kept
                    outs.append(np.load(path))
                    os.unlink(path)
                diff = max(float(np.abs(o - outs[0]).max()) for o in outs)
                times: list[list[float]] = [[] for _ in workers]
                for r in range(args.rounds):
                    for t, worker in zip(times, workers, strict=True):
                        t.append(worker.ask(op="frame", i=r + 1)["ms"])
                        time.sleep(args.pause)
                cells = [f"{statistics.median(t):.1f} ({min(t):.1f}-{max(t):.1f})" for t in times]
                ratio = statistics.median(times[-1]) / statistics.median(times[0])
                row = f"| {model} | {size} | {args.rounds} | {' | '.join(cells)} | {ratio:.2f}"
                print(f"{row} | {diff:.1e} |", flush=True)
    finally:
        for worker in workers:
            worker.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
