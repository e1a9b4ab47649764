"""Denoisers side by side: exported models (ONNX Runtime) and Intel Open Image Denoise.

Speed: every contender denoises the same synthetic frames at each size, interleaved (A B C A B
C ...) after a warm-up round, so that a busy machine slows all of them alike; the report keeps
every time, the median and the spread (min, max), and the time per pixel. Models run with
their state carried from frame to frame, as in production; OIDN is single-frame.
Quality: every contender denoises whole sequences with references (tau-PSNR pooled over the
frames, SSIM, TRMAE; runtime.metrics).

Torch-free. OIDN comes from the optional `pyoidn` package (extra `[bench]`): the RT filter,
HDR colour with albedo and normal, quality "high" / "balanced" / "fast".
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InputError
from .metrics import SequenceMetrics
from .synthetic import synthetic_frames

Frame = Mapping[str, np.ndarray]
OIDN_QUALITIES = ("high", "balanced", "fast")
OIDN_BUFFERS = ("color", "albedo", "normal")


@dataclass
class Contender:
    """One denoiser under test: `denoise(frame)` -> (3, H, W); `reset()` starts a sequence."""

    name: str
    denoise: Callable[[Frame], np.ndarray]
    reset: Callable[[], None]
    buffers: tuple[str, ...]
    prepare: Callable[[Frame], Any] = field(default=lambda frame: frame)  # untimed conversion


def _hwc(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.moveaxis(a, 0, -1), dtype=np.float32)


def oidn_contender(quality: str = "high") -> Contender:
    """Open Image Denoise (RT filter, HDR, albedo + normal), through `pyoidn`."""
    if quality not in OIDN_QUALITIES:
        raise InputError(f"OIDN quality {quality!r}: expected one of {', '.join(OIDN_QUALITIES)}")
    try:
        import pyoidn
    except ImportError:
        raise InputError("OIDN needs the pyoidn package: pip install 'rtdenoise[bench]'") from None

    def prepare(frame: Frame) -> tuple[np.ndarray, ...]:
        color = _hwc(np.maximum(frame["color"], 0.0))
        albedo = _hwc(np.clip(frame["albedo"], 0.0, 1.0))
        return color, albedo, _hwc(frame["normal"])

    def denoise(prepared: tuple[np.ndarray, ...]) -> np.ndarray:
        color, albedo, normal = prepared
        out = pyoidn.denoise(color, albedo, normal, hdr=True, quality=quality)
        return np.moveaxis(out, -1, 0)

    return Contender(f"OIDN {quality}", denoise, lambda: None, OIDN_BUFFERS, prepare)


def model_contender(name: str, denoiser: Any) -> Contender:
    """A `rtdenoise.runtime.Denoiser` (or any object with process/reset/required_buffers)."""
    return Contender(name, denoiser.process, denoiser.reset, tuple(denoiser.required_buffers))


# Pause after each contender's frame (untimed): ONNX Runtime's idle workers spin for a while
# after a run by default (the portable path keeps that default), and that spin took the cores
# from whichever contender ran next (measured on 2 cores: wskp's fast path at 320x240, 57-70 ms
# right after a spinning session, 40 ms after a sleeping one; a 20 ms pause was not enough,
# 100 ms was).
SETTLE_S = 0.1


def time_interleaved(
    contenders: Sequence[Contender],
    frames: Sequence[Frame],
    repeats: int,
    warmup: int = 1,
    settle_s: float = SETTLE_S,
) -> dict[str, list[float]]:
    """Milliseconds per frame of each contender, rounds interleaved: warm-up rounds first
    (not kept), then `repeats` rounds; frame i of the sequence goes to round i (cycling).
    Sleeps `settle_s` after each frame, so that one contender's idle threads do not run
    into the next one's time."""
    prepared = [[c.prepare(f) for f in frames] for c in contenders]
    for c in contenders:
        c.reset()
    times: dict[str, list[float]] = {c.name: [] for c in contenders}
    for r in range(warmup + repeats):
        for c, inputs in zip(contenders, prepared, strict=True):
            frame = inputs[r % len(inputs)]
            t0 = time.perf_counter()
            c.denoise(frame)
            dt = (time.perf_counter() - t0) * 1e3
            if r >= warmup:
                times[c.name].append(dt)
            time.sleep(settle_s)
    return times


def summarize_times(ms: Sequence[float], pixels: int) -> dict[str, float]:
    """Median, min, max (ms) and the median time per pixel (ns)."""
    median = statistics.median(ms)
    return {
        "median_ms": median,
        "min_ms": min(ms),
        "max_ms": max(ms),
        "ns_per_pixel": median * 1e6 / pixels,
    }


REFERENCE_PIXELS = 1280 * 720
MORE_FRAMES_UP_TO = 4


def repeats_for_size(repeats: int, h: int, w: int) -> int:
    """Timed frames at H x W: `repeats` at 720p and above; smaller frames get more, in
    proportion to their pixels, up to MORE_FRAMES_UP_TO x (small frames are short, and their
    times are noisier: a few scheduler slices are a large part of them)."""
    scaled = round(repeats * REFERENCE_PIXELS / max(h * w, 1))
    return max(repeats, min(MORE_FRAMES_UP_TO * repeats, scaled))


def speed(
    contenders: Sequence[Contender],
    sizes: Iterable[tuple[int, int]],
    repeats: int = 5,
    frames: int = 4,
    progress: Callable[[str], None] = lambda _msg: None,
) -> list[dict[str, Any]]:
    """Per size (H, W): every contender's times (`repeats_for_size` frames) and summary."""
    buffers = sorted({b for c in contenders for b in c.buffers})
    rows = []
    for h, w in sizes:
        progress(f"{w}x{h}")
        seq = synthetic_frames(buffers, frames, h, w)
        n = repeats_for_size(repeats, h, w)
        times = time_interleaved(contenders, seq, n)
        rows.append(
            {
                "size": [h, w],
                "repeats": n,
                "times_ms": times,
                "summary": {n: summarize_times(t, h * w) for n, t in times.items()},
            }
        )
    return rows


def quality(
    contenders: Sequence[Contender],
    sequences: Sequence[tuple[str, Sequence[Frame], Sequence[np.ndarray]]],
    progress: Callable[[str], None] = lambda _msg: None,
) -> dict[str, dict[str, Any]]:
    """Per contender: PSNR, SSIM, TRMAE per sequence (frames with state) and their means."""
    out: dict[str, dict[str, Any]] = {}
    for c in contenders:
        progress(f"quality: {c.name}")
        per_seq = {}
        for name, frames, references in sequences:
            c.reset()
            metrics = SequenceMetrics()
            for frame, ref in zip(frames, references, strict=True):
                metrics.add(np.asarray(c.denoise(c.prepare(frame)), np.float32), ref)
            s = metrics.summary()
            per_seq[name] = {k: s[k] for k in ("psnr", "ssim", "trmae")}
        out[c.name] = {
            "sequences": per_seq,
            "mean": {
                k: float(np.mean([v[k] for v in per_seq.values()]))
                for k in ("psnr", "ssim", "trmae")
            },
        }
    return out


def noisy_quality(
    sequences: Sequence[tuple[str, Sequence[Frame], Sequence[np.ndarray]]],
) -> dict[str, Any]:
    """The same scores for the noisy input itself (the baseline every denoiser must beat)."""
    identity = Contender("noisy input", lambda f: f["color"], lambda: None, ("color",))
    return quality([identity], sequences)["noisy input"]
