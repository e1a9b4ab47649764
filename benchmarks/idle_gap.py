"""What an idle gap before a frame costs, with and without thread placement: frames back to
back vs each after a pause, for `Denoiser(pin_threads=False)` and `(pin_threads=True)`, in
alternating blocks (A B C D A B C D), medians per block.

    python benchmarks/idle_gap.py --model demo:nbg --size 320x240 --size 1280x720

`denoise-bench compare` pauses 100 ms after every timed frame (runtime.compare.SETTLE_S) so that
one contender's spinning threads cannot slow the next, and a host renders between frames; this
measures what that pause adds to a frame by itself, and what `runtime.placement` wins back.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts

from rtdenoise.runtime.denoiser import Denoiser  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.placement import release_workers  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", action="append", help="model (repeatable; default demo:wskp)")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--pause", type=float, default=0.1, help="seconds of idle before a frame")
    ap.add_argument("--frames", type=int, default=15, help="frames per block")
    ap.add_argument("--blocks", type=int, default=2, help="blocks of each kind")
    args = ap.parse_args(argv)
    tune_allocator()
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}")
    print(f"# {' '.join(sys.argv)}")
    print(
        "| model | size | pin_threads | back to back ms (per block) "
        "| after a pause ms (per block) |\n|---|---|---|---|---|"
    )
    for model in args.model or ["demo:wskp"]:
        dens = {pin: Denoiser(model, pin_threads=pin) for pin in (False, True)}
        for size in args.size or ["320x240", "1280x720"]:
            w, h = (int(v) for v in size.split("x"))
            frames = synthetic_frames(dens[True].required_buffers, 4, h, w)
            for den in dens.values():
                for i in range(3):  # warm-up (and the size change's new history)
                    den.process(frames[i % 4])
            medians = {(pin, pause): [] for pin in dens for pause in (0.0, args.pause)}
            for _ in range(args.blocks):
                for pin, pause in medians:
                    if not pin:
                        release_workers()  # the unplaced runs get unplaced workers
                    times = []
                    for r in range(args.frames):
                        time.sleep(pause)
                        t0 = time.perf_counter()
                        dens[pin].process(frames[r % 4])
                        times.append((time.perf_counter() - t0) * 1e3)
                    medians[pin, pause].append(statistics.median(times))
            for pin in dens:
                cells = [" / ".join(f"{m:.1f}" for m in medians[pin, p]) for p in (0.0, args.pause)]
                print(f"| {model} | {size} | {pin} | {cells[0]} | {cells[1]} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
