"""Two ONNX files of one model (e.g. before and after an export change), side by side.

Whole frames, interleaved A B A B ... in one process (100 ms pause after each frame), state
carried, synthetic frames, after one warm-up frame: median (min-max) ms per frame of each, the
ratio, and the largest output difference over all frames. Then each file's peak RSS in a
fresh process over 3 frames (`--no-memory` skips it).

    python benchmarks/model_ab.py before.onnx rtdenoise/assets/models/affinity.onnx \\
        --size 1280x720 --rounds 16 --threads 2
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts

import numpy as np  # noqa: E402

from rtdenoise.runtime.denoiser import Denoiser  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402


def peak_rss_mib(model: str, h: int, w: int, threads: int | None) -> int:
    """Peak RSS (MiB) of a fresh process that runs 3 frames of `model` (VmHWM: unlike
    ru_maxrss it starts afresh at exec, not at the parent's size)."""
    code = (
        "from rtdenoise.runtime.denoiser import Denoiser\n"
        "from rtdenoise.runtime.sequences.synthetic import synthetic_frames\n"
        f"d = Denoiser({model!r}, threads={threads!r})\n"
        f"for f in synthetic_frames(d.required_buffers, 3, {h}, {w}): d.process(f)\n"
        "hwm = [ln for ln in open('/proc/self/status') if ln.startswith('VmHWM')][0]\n"
        "print(int(hwm.split()[1]) // 1024)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(out.stdout.split()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a", help="the first ONNX file (or demo:<family>)")
    ap.add_argument("b", help="the second")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    ap.add_argument("--rounds", type=int, default=16, help="timed frames of each")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--no-memory", action="store_true", help="skip the peak-RSS processes")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    den = {k: Denoiser(m, threads=args.threads) for k, m in (("a", args.a), ("b", args.b))}
    frames = synthetic_frames(den["a"].required_buffers, args.rounds + 1, h, w)
    ms: dict[str, list[float]] = {"a": [], "b": []}
    diff = 0.0
    for i, frame in enumerate(frames):
        outs = {}
        for k, d in den.items():
            t = time.perf_counter()
            outs[k] = np.array(d.process(frame))
            if i:  # the first frame warms up
                ms[k].append(1000 * (time.perf_counter() - t))
            time.sleep(0.1)
        diff = max(diff, float(np.abs(outs["a"] - outs["b"]).max()))
    med = {k: statistics.median(v) for k, v in ms.items()}
    print(f"{args.size}, {args.rounds} frames each, threads {args.threads}")
    print("| file | ms per frame, median (min-max) | peak RSS |")
    print("|---|---:|---:|")
    for k, m in (("a", args.a), ("b", args.b)):
        rss = "-" if args.no_memory else f"{peak_rss_mib(m, h, w, args.threads)} MiB"
        print(f"| {m} | {med[k]:.0f} ({min(ms[k]):.0f}-{max(ms[k]):.0f}) | {rss} |")
    print(f"b / a: {med['b'] / med['a']:.3f}; max |a - b| over the frames: {diff:.2e}")


if __name__ == "__main__":
    main()
