"""Soak: many frames through one `Denoiser`, on the fast and the portable path.

Does time per frame or resident memory creep up over a long run? Each path runs in its own
child process (so that one path's memory does not count against the other): one `Denoiser`
processes `--frames` frames (default 1000) of a synthetic shot made from the committed
seq_000 (its buffers and motion cycled, fresh 1-spp-like noise on the reference every frame,
scaled up to `--size`), and every `--bad-every` frames a broken one (NaN block, 1e30 block,
firefly, zero albedo, wild motion, in turn), so that the guard and the resets are soaked too.

Reported per path: median time per frame and resident set size (RSS, from /proc/self/statm)
over the first 100 and the last 100 frames, the guard's totals, and "aged / fresh": after the
run, the same frames alternately through the long-running instance and a new one (the load
on a shared machine hits both alike, so their ratio is what the run's age costs). Linux only
(RSS).

    . .venv/bin/activate
    python benchmarks/soak.py                       # demo:afn, 1000 frames 128x128, both paths
    python benchmarks/soak.py --model demo:wskp --frames 2000 --size 256x256
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

WINDOW = 100
AB_FRAMES = 50  # aged vs fresh: 2 x 50 pairs of frames, the last 50 measured


def rss_mb() -> float:
    """Resident set size of this process in MiB (Linux)."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def _upscale(a: np.ndarray, fy: int, fx: int, size: tuple[int, int]) -> np.ndarray:
    return np.ascontiguousarray(a.repeat(fy, 1).repeat(fx, 2)[:, : size[0], : size[1]])


def shot(size: tuple[int, int]) -> tuple[list[dict[str, np.ndarray]], list[np.ndarray]]:
    """The committed seq_000 (buffers, references), nearest-upscaled to `size` (H, W)."""
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame, read_reference
    from rtdenoise.shipped import sample_sequences

    seq = sample_sequences()[0]
    buffers, refs = [], []
    for path in find_frames(seq):
        b = read_frame(path).buffers
        ref = read_reference(seq / f"ref_{path.stem.split('_')[-1]}.exr")
        h, w = b["color"].shape[1:]
        fy, fx = -(-size[0] // h), -(-size[1] // w)
        b = {k: _upscale(v, fy, fx, size) for k, v in b.items()}
        b["motion"] = b["motion"] * np.float32([fx, fy])[:, None, None]
        buffers.append(b)
        refs.append(_upscale(ref, fy, fx, size))
    return buffers, refs


def broken(b: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    """The k-th kind of broken frame (a copy)."""
    b = {name: v.copy() for name, v in b.items()}
    h, w = b["color"].shape[1:]
    block = np.s_[:, h // 4 : h // 2, w // 4 : w // 2]
    kind = k % 5
    if kind == 0:
        b["color"][block] = np.nan
    elif kind == 1:
        b["color"][block] = 1e30
    elif kind == 2:
        b["color"][:, h // 2, w // 2] = 1e4
    elif kind == 3:
        b["albedo"][:] = 0.0
    else:
        b["motion"][:] = 1e30
    return b


def soak(
    model: str,
    fast: bool,
    frames: int,
    size: tuple[int, int],
    bad_every: int,
    threads: int | None = None,
) -> dict:
    """Run one path in this process; the measurements as a dict."""
    from rtdenoise.runtime import Denoiser

    buffers, refs = shot(size)
    rng = np.random.default_rng(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the fast kernels must be there
        den = Denoiser(model, fast_kernels=fast, threads=threads)
    times, rss, finite = [], [], True
    for t in range(frames):
        b = dict(buffers[t % len(buffers)])
        b["color"] = refs[t % len(refs)] * rng.exponential(1.0, refs[0].shape).astype(np.float32)
        if bad_every and t % bad_every == bad_every - 1:
            b = broken(b, t // bad_every)
        t0 = time.perf_counter()
        out = den.process(b)
        times.append((time.perf_counter() - t0) * 1e3)
        finite = finite and bool(np.isfinite(out).all())
        rss.append(rss_mb())
    # Aged vs fresh, interleaved (A B A B ...): the load on the machine hits both alike, so
    # their ratio shows whether the long-running instance got slower than a new one.
    fresh = Denoiser(model, fast_kernels=fast, threads=threads)
    aged_ms, fresh_ms = [], []
    for t in range(frames, frames + 2 * AB_FRAMES):
        b = dict(buffers[t % len(buffers)])
        b["color"] = refs[t % len(refs)] * rng.exponential(1.0, refs[0].shape).astype(np.float32)
        for instance, record in ((den, aged_ms), (fresh, fresh_ms)):
            t0 = time.perf_counter()
            instance.process(b)
            record.append((time.perf_counter() - t0) * 1e3)
    totals = den.guard_totals
    return {
        "ms_aged": statistics.median(aged_ms[AB_FRAMES:]),  # the fresh one warmed up first
        "ms_fresh": statistics.median(fresh_ms[AB_FRAMES:]),
        "model": model,
        "path": "fast" if fast else "portable",
        "frames": frames,
        "size": list(size),
        "ms_first": statistics.median(times[:WINDOW]),
        "ms_last": statistics.median(times[-WINDOW:]),
        "rss_first": statistics.mean(rss[:WINDOW]),
        "rss_last": statistics.mean(rss[-WINDOW:]),
        "rss_max": max(rss),
        "ms_windows": [statistics.median(times[i : i + WINDOW]) for i in range(0, frames, WINDOW)],
        "all_finite": finite,
        "guard": {
            "nonfinite_pixels": totals.nonfinite_pixels,
            "clamped": totals.clamped,
            "outliers": totals.outliers,
            "unusable_frames": totals.unusable_frames,
            "resets": totals.resets,
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="demo:afn")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--size", default="128x128", help="WxH")
    ap.add_argument("--bad-every", type=int, default=50, help="a broken frame every N (0: none)")
    ap.add_argument("--threads", type=int, help="ONNX Runtime threads (default: all cores)")
    ap.add_argument("--path", choices=["fast", "portable"], help="run one path here (JSON out)")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    if args.frames < 2 * WINDOW:
        ap.error(f"--frames must be >= {2 * WINDOW}")
    if args.path:
        fast = args.path == "fast"
        result = soak(args.model, fast, args.frames, (h, w), args.bad_every, args.threads)
        print(json.dumps(result))
        return
    results = []
    for path in ("fast", "portable"):
        cmd = [sys.executable, __file__, "--path", path, "--model", args.model]
        cmd += ["--frames", str(args.frames), "--size", args.size]
        cmd += ["--bad-every", str(args.bad_every)]
        cmd += ["--threads", str(args.threads)] if args.threads else []
        proc = subprocess.run(cmd, capture_output=True, text=True, check=True)
        results.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    r0 = results[0]
    print(
        f"{r0['model']}, {r0['frames']} frames {w}x{h}, a broken frame every "
        f"{args.bad_every}, threads {args.threads or 'all'}; first / last {WINDOW} frames\n"
    )
    print("| path | ms/frame first | ms/frame last | aged / fresh | RSS MiB first | RSS MiB last |"
          " RSS max | all finite | guard |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---|---|")
    for r in results:
        g = r["guard"]
        print(
            f"| {r['path']} | {r['ms_first']:.1f} | {r['ms_last']:.1f} | "
            f"{r['ms_aged']:.1f} / {r['ms_fresh']:.1f} | {r['rss_first']:.0f} | "
            f"{r['rss_last']:.0f} | {r['rss_max']:.0f} | {r['all_finite']} | "
            f"{g['nonfinite_pixels']} NaN px, {g['clamped']} clamped, {g['outliers']} outliers, "
            f"{g['unusable_frames']} unusable frames |"
        )
    print(f"\nms/frame, median of each {WINDOW} frames in turn (load on the machine shows here):")
    for r in results:
        print(f"- {r['path']}: " + ", ".join(f"{v:.0f}" for v in r["ms_windows"]))


if __name__ == "__main__":
    main()
