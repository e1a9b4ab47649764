"""Memory and frame time of several Denoisers in one process: one CPU arena shared by all
sessions (`Denoiser(shared_arena=True)`, as `denoise-bench compare` runs) vs an arena of each
session's own (the default).

    python benchmarks/shared_arena.py --model demo:afn --model demo:wskp --model demo:nbg \
        --size 320x240 --size 1280x720 --size 1920x1080 --runs 2

Each run is a fresh process (the shared arena is process-wide), the two kinds alternating
(A B A B ...). In a run every model at every size (a Denoiser each, as `denoise-bench compare`
has) denoises in turn, 100 ms apart; the table gives the median ms per frame after a warm-up
round and the process's peak resident memory.
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


def _worker(models: list[str], sizes: list[str], rounds: int, shared: bool) -> dict:
    import resource

    from rtdenoise.runtime.denoiser import Denoiser
    from rtdenoise.runtime.memory import tune_allocator
    from rtdenoise.runtime.sequences.synthetic import synthetic_frames

    tune_allocator()
    runs = []  # (model, size, denoiser, frames)
    for size in sizes:
        w, h = (int(v) for v in size.split("x"))
        for model in models:
            den = Denoiser(model, shared_arena=shared)
            runs.append((model, size, den, synthetic_frames(den.required_buffers, 3, h, w)))
    ms: dict[str, list[float]] = {f"{m} {s}": [] for m, s, _, _ in runs}
    for r in range(rounds + 1):
        for model, size, den, frames in runs:
            t0 = time.perf_counter()
            den.process(frames[r % len(frames)])
            if r:  # round 0 warms up
                ms[f"{model} {size}"].append((time.perf_counter() - t0) * 1e3)
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
        result = _worker(models, sizes, args.rounds, args.worker == "shared")
        print(json.dumps(result))
        return 0
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC; {' '.join(sys.argv)}")
    print("| arena | size | " + " | ".join(f"{m} ms" for m in models) + " | peak GiB |")
    print("|---|---|" + "---:|" * (len(models) + 1))
    for _ in range(args.runs):
        for kind in ("own", "shared"):
            cmd = [sys.executable, __file__, "--worker", kind, f"--rounds={args.rounds}"]
            cmd += [f"--model={m}" for m in models] + [f"--size={s}" for s in sizes]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            res = json.loads(out.strip().splitlines()[-1])
            for k, size in enumerate(sizes):
                cells = " | ".join(f"{res['ms'][f'{m} {size}']:.1f}" for m in models)
                peak = f"{res['peak_gib']:.2f}" if k == len(sizes) - 1 else ""
                print(f"| {kind} | {size} | {cells} | {peak} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
