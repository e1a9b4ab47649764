"""Denoisers side by side: exported models (ONNX Runtime) and Intel Open Image Denoise.

Speed: every contender denoises the same synthetic frames at every size, all interleaved in
the same rounds (A B C A B C ...) after a warm-up round, so that a busy machine slows all of
them and all sizes alike; the report keeps every time, the median and the spread (min, max),
and the time per pixel. Models run with their state carried from frame to frame, as in
production; OIDN is single-frame.
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
    # A new contender of the same denoiser with its own state (one per frame size, so that
    # sizes can be interleaved); None: stateless, this one serves every size.
    fresh: Callable[[], Contender] | None = None


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


def model_contender(name: str, denoiser: Any, remake: Callable[[], Any] | None = None) -> Contender:
    """A `rtdenoise.runtime.Denoiser` (or any object with process/reset/required_buffers);
    `remake()` builds another one like it (for `Contender.fresh`)."""
    fresh = None if remake is None else (lambda: model_contender(name, remake(), remake))
    buffers = tuple(denoiser.required_buffers)
    return Contender(name, denoiser.process, denoiser.reset, buffers, fresh=fresh)


# Pause after each contender's frame (untimed): ONNX Runtime's idle workers spin for a while
# after a run by default (the portable path keeps that default), and that spin took the cores
# from whichever contender ran next (measured on 2 cores: wskp's fast path at 320x240, 57-70 ms
# right after a spinning session, 40 ms after a sleeping one; a 20 ms pause was not enough,
# 100 ms was).
SETTLE_S = 0.1


@dataclass
class Slot:
    """One contender on one frame sequence, `per_round` frames in each round."""

    key: tuple
    contender: Contender
    frames: Sequence[Frame]
    per_round: int = 1


def time_rounds(
    slots: Sequence[Slot], rounds: int, warmup: int = 1, settle_s: float = SETTLE_S
) -> dict[tuple, list[float]]:
    """Milliseconds per frame of each slot, in interleaved rounds (every slot's `per_round`
    frames in turn, A B C A B C ...): `warmup` rounds first (not kept), then `rounds`. Each
    slot walks its sequence cyclically, its state carried. Sleeps `settle_s` after each frame,
    so that one contender's idle threads do not run into the next one's time."""
    prepared = [[s.contender.prepare(f) for f in s.frames] for s in slots]
    for s in slots:
        s.contender.reset()
    times: dict[tuple, list[float]] = {s.key: [] for s in slots}
    walked = [0] * len(slots)
    for r in range(warmup + rounds):
        for i, (slot, inputs) in enumerate(zip(slots, prepared, strict=True)):
            for _ in range(slot.per_round if r >= warmup else 1):
                frame = inputs[walked[i] % len(inputs)]
                walked[i] += 1
                t0 = time.perf_counter()
                slot.contender.denoise(frame)
                dt = (time.perf_counter() - t0) * 1e3
                if r >= warmup:
                    times[slot.key].append(dt)
                time.sleep(settle_s)
    return times


def time_interleaved(
    contenders: Sequence[Contender],
    frames: Sequence[Frame],
    repeats: int,
    warmup: int = 1,
    settle_s: float = SETTLE_S,
) -> dict[str, list[float]]:
    """`time_rounds` of `contenders` on one sequence: {name: ms per frame}."""
    slots = [Slot((c.name,), c, frames) for c in contenders]
    times = time_rounds(slots, repeats, warmup, settle_s)
    return {key[0]: t for key, t in times.items()}


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


def frames_per_round(h: int, w: int) -> int:
    """Timed frames per round at H x W: 1 at 720p and above; smaller frames get more, in
    proportion to their pixels, up to MORE_FRAMES_UP_TO (small frames are short, and their
    times are noisier: a few scheduler slices are a large part of them)."""
    return min(MORE_FRAMES_UP_TO, max(1, round(REFERENCE_PIXELS / max(h * w, 1))))


def speed(
    contenders: Sequence[Contender],
    sizes: Iterable[tuple[int, int]],
    repeats: int = 5,
    frames: int = 4,
    progress: Callable[[str], None] = lambda _msg: None,
) -> list[dict[str, Any]]:
    """Per size (H, W): every contender's times and their summary. All sizes are timed in the
    same interleaved rounds (`repeats` of them, `frames_per_round` frames per size), each
    contender at each size with a state of its own (`Contender.fresh`): a machine whose speed
    drifts during the run slows every size alike, so times per pixel compare across sizes."""
    sizes = list(sizes)
    buffers = sorted({b for c in contenders for b in c.buffers})
    slots = []
    for k, (h, w) in enumerate(sizes):
        seq = synthetic_frames(buffers, frames, h, w)
        for c in contenders:
            own = c if k == 0 or c.fresh is None else c.fresh()
            slots.append(Slot((h, w, c.name), own, seq, frames_per_round(h, w)))
    progress(", ".join(f"{w}x{h}" for h, w in sizes))
    times = time_rounds(slots, repeats)
    rows = []
    for h, w in sizes:
        size_times = {c.name: times[(h, w, c.name)] for c in contenders}
        rows.append(
            {
                "size": [h, w],
                "repeats": repeats * frames_per_round(h, w),
                "times_ms": size_times,
                "summary": {n: summarize_times(t, h * w) for n, t in size_times.items()},
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
