"""Whole-frame time of `Denoiser` variants, interleaved in one run (A B C A B C ...).

Each variant is one `Denoiser` built from keyword arguments, e.g. `fast:fast_kernels=1` and
`portable:fast_kernels=0`; every variant of a model denoises the same synthetic frames (state
carried, `runtime.synthetic`) in interleaved rounds after one warm-up round, size by size.
Reports the median ms per frame (min-max) and each variant's median over the first
variant's. Like the CLIs, it lets idle OpenMP workers sleep (OMP_WAIT_POLICY=PASSIVE unless
set) and tunes the allocator; like `denoise-bench compare`, it pauses 100 ms after each frame
(`compare.SETTLE_S`: a spinning ORT session otherwise slows the variant timed after it).

    python benchmarks/runtime_paths.py --model demo:wskp --size 64x64 --size 1280x720 \
        --variant fast:fast_kernels=1 --variant portable:fast_kernels=0

Values: integers, `none`, `auto`, or true/false (1/0 for booleans: fast_kernels, spinning).
A key with a leading underscore sets that attribute after construction (`_serial_below=N`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts

import numpy as np  # noqa: E402

from rtdenoise.runtime.bridge import BRIDGES  # noqa: E402
from rtdenoise.runtime.denoiser import Denoiser  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.sequences.compare import model_contender, summarize_times, time_interleaved  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402

BOOLS = {"fast_kernels", "spinning", "io_binding"}


def parse_variant(text: str) -> tuple[str, dict]:
    """`name:key=value,key=value` -> (name, Denoiser kwargs)."""
    name, _, rest = text.partition(":")
    kwargs: dict = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        if value.lower() in ("none", ""):
            kwargs[key] = None
        elif value.lower() == "auto":
            kwargs[key] = "auto"
        elif value in BRIDGES:  # fast_kernels=native: the bridge
            kwargs[key] = value
        elif key in BOOLS or value.lower() in ("true", "false"):
            kwargs[key] = value.lower() in ("1", "true")
        else:
            kwargs[key] = int(value)
    return name, kwargs


def default_repeats(h: int, w: int) -> int:
    """More frames where they are cheap: 41 at 64x64, 7 at 720p."""
    return int(np.clip(2.0e6 / (h * w), 7, 41)) | 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", action="append", help="demo:<family> or .onnx (repeatable)")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--variant", action="append", required=True, help="name:key=value,...")
    ap.add_argument("--repeats", type=int, default=0, help="timed frames (0: by size)")
    ap.add_argument("--json", help="also write every time here")
    args = ap.parse_args(argv)
    tune_allocator()
    models = args.model or ["demo:afn", "demo:wskp", "demo:nbg", "demo:crossreg"]
    sizes = [tuple(int(v) for v in s.split("x"))[::-1] for s in args.size or ["1280x720"]]
    variants = [parse_variant(v) for v in args.variant]
    names = [n for n, _ in variants]
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, {os.cpu_count()} CPUs, load {os.getloadavg()}")
    print(f"# {' '.join(sys.argv)}")
    results = []
    for model in models:
        contenders = []
        for n, kw in variants:
            den = Denoiser(model, **{k: v for k, v in kw.items() if not k.startswith("_")})
            for k, v in kw.items():
                if k.startswith("_"):  # a plain attribute, e.g. _serial_below=65536
                    setattr(den, k[1:], v)
            contenders.append(model_contender(n, den))
        for h, w in sizes:
            repeats = args.repeats or default_repeats(h, w)
            frames = synthetic_frames(sorted({b for c in contenders for b in c.buffers}), 4, h, w)
            times = time_interleaved(contenders, frames, repeats)
            summary = {n: summarize_times(t, h * w) for n, t in times.items()}
            base = summary[names[0]]["median_ms"]
            cells = [
                f"{s['median_ms']:.1f} ({s['min_ms']:.1f}-{s['max_ms']:.1f}) "
                f"x{s['median_ms'] / base:.2f}"
                for s in (summary[n] for n in names)
            ]
            print(f"| {model} | {w}x{h} | {repeats} | " + " | ".join(cells) + " |", flush=True)
            results.append({"model": model, "size": [h, w], "times_ms": times})
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"variants": args.variant, "results": results}, f, indent=1)
    print("| model | size | frames | " + " | ".join(names) + " |")
    print(f"cells: median ms per frame (min-max) x ratio to {names[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
