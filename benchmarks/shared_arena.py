"""Memory and frame time of several Denoisers in one process: one CPU arena shared by all
sessions (`Denoiser(shared_arena=True)`, the default) vs an arena of each session's own.

    python benchmarks/shared_arena.py --model demo:afn --model demo:wskp --model demo:nbg \
        --size 1920x1080 --runs 2

Each run is a fresh process (the shared arena is process-wide), the two kinds alternating
(A B A B ...). In a run every model denoises the same frames in turn, A B C A B C ..., 100 ms
apart as `denoise-bench compare` does; the table gives each model's median ms per frame after
a warm-up round and the process's peak resident memory.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts


def _worker(models: list[str], size: str, rounds: int, shared: bool) -> dict:
    import resource

    from rtdenoise.runtime.denoiser import Denoiser
    from rtdenoise.runtime.memory import tune_allocator
    from rtdenoise.runtime.synthetic import synthetic_frames

    tune_allocator()
    w, h = (int(v) for v in size.split("x"))
    dens = [Denoiser(m, shared_arena=shared) for m in models]
    frames = synthetic_frames(sorted({b for d in dens for b in d.required_buffers}), 3, h, w)
    ms: dict[str, list[float]] = {m: [] for m in models}
    for r in range(rounds + 1):
        for model, den in zip(models, dens, strict=True):
            t0 = time.perf_counter()
            den.process(frames[r % len(frames)])
            if r:  # round 0 warms up
                ms[model].append((time.perf_counter() - t0) * 1e3)
            time.sleep(0.1)
    peak_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux
    return {"ms": {m: statistics.median(t) for m, t in ms.items()}, "peak_gib": peak_gib}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", action="append", help="model (repeatable; default the light demos)")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable; default 1080p)")
    ap.add_argument("--rounds", type=int, default=4, help="timed rounds per run")
    ap.add_argument("--runs", type=int, default=2, help="processes of each kind")
    ap.add_argument("--worker", choices=["shared", "own"], help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    models = args.model or ["demo:afn", "demo:wskp", "demo:nbg"]
    sizes = args.size or ["1920x1080"]
    if args.worker:
        result = _worker(models, sizes[0], args.rounds, args.worker == "shared")
        print(json.dumps(result))
        return 0
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC; {' '.join(sys.argv)}")
    print("| size | arena | " + " | ".join(f"{m} ms" for m in models) + " | peak GiB |")
    print("|---|---|" + "---:|" * (len(models) + 1))
    for size in sizes:
        for _ in range(args.runs):
            for kind in ("own", "shared"):
                cmd = [sys.executable, __file__, "--worker", kind, "--size", size]
                cmd += [f"--model={m}" for m in models] + [f"--rounds={args.rounds}"]
                out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
                res = json.loads(out.strip().splitlines()[-1])
                cells = " | ".join(f"{res['ms'][m]:.1f}" for m in models)
                print(f"| {size} | {kind} | {cells} | {res['peak_gib']:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
