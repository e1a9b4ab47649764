"""Denoisers side by side: exported models (ONNX Runtime) and Intel Open Image Denoise.

Speed: every contender denoises the same synthetic frames at every size, all interleaved in
the same rounds (A B C A B C ...) after a warm-up frame each (the sizes warm up smallest
first, and one that would not fit in memory is left out: `MemoryWatch`), so that a busy
machine slows all of them and all sizes alike; the report keeps every time, the median and
the spread (min, max), and the time per pixel. Models run with their state carried from frame
to frame, as in production; OIDN is single-frame.
Quality: every contender denoises whole sequences with references (tau-PSNR pooled over the
frames, SSIM, TRMAE; runtime.metrics).

Torch-free. OIDN comes from the optional `pyoidn` package (extra `[bench]`): the RT filter,
HDR colour with albedo and normal, quality "high" / "balanced" / "fast".
"""

from __future__ import annotations

import inspect
import statistics
import time
from collections.abc import Callable, Collection, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
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
    # What a camera cut inside a sequence does (a model's reset, which keeps what an online
    # model learned); None: `reset`.
    cut: Callable[[], None] | None = None


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
    return Contender(
        name, denoiser.process, _sequence_start(denoiser), buffers, fresh=fresh, cut=denoiser.reset
    )


def _sequence_start(denoiser: Any) -> Callable[[], None]:
    """What starts a sequence: a reset that restarts an online model's learning too, so that
    every sequence (and every timed size) starts from the model's own weights."""
    if "learning" in inspect.signature(denoiser.reset).parameters:
        return lambda: denoiser.reset(learning=True)
    return denoiser.reset


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


class _Rounds:
    """Slots under way: their prepared frames, how far each has walked its sequence (cyclically,
    its state carried) and its times."""

    def __init__(self, settle_s: float) -> None:
        self.settle_s = settle_s
        self.slots: list[Slot] = []
        self.inputs: list[list[Any]] = []
        self.walked: list[int] = []
        self.times: dict[tuple, list[float]] = {}

    def add(self, slots: Sequence[Slot]) -> range:
        """Prepare the slots' frames (untimed) and reset their contenders; their indices."""
        first = len(self.slots)
        self.inputs += [[s.contender.prepare(f) for f in s.frames] for s in slots]
        for s in slots:
            s.contender.reset()
            self.slots.append(s)
            self.walked.append(0)
            self.times[s.key] = []
        return range(first, len(self.slots))

    def play(self, indices: Sequence[int], timed: bool) -> None:
        """One round over the slots at `indices`: `per_round` frames each if timed (kept),
        else one (a warm-up). Sleeps `settle_s` after each frame, so that one contender's idle
        threads do not run into the next one's time."""
        for i in indices:
            slot, inputs = self.slots[i], self.inputs[i]
            for _ in range(slot.per_round if timed else 1):
                frame = inputs[self.walked[i] % len(inputs)]
                self.walked[i] += 1
                t0 = time.perf_counter()
                slot.contender.denoise(frame)
                dt = (time.perf_counter() - t0) * 1e3
                if timed:
                    self.times[slot.key].append(dt)
                time.sleep(self.settle_s)


def time_rounds(
    slots: Sequence[Slot], rounds: int, warmup: int = 1, settle_s: float = SETTLE_S
) -> dict[tuple, list[float]]:
    """Milliseconds per frame of each slot, in interleaved rounds (every slot's `per_round`
    frames in turn, A B C A B C ...): `warmup` rounds first (not kept), then `rounds`. Each
    slot walks its sequence cyclically, its state carried. Sleeps `settle_s` after each frame,
    so that one contender's idle threads do not run into the next one's time."""
    under_way = _Rounds(settle_s)
    every = under_way.add(slots)
    for r in range(warmup + rounds):
        under_way.play(every, timed=r >= warmup)
    return under_way.times


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


GIB = 1 << 30


def _proc_kib(path: str, field: str) -> int | None:
    """A `field:  N kB` line of a /proc file, in bytes (None where there is none: not Linux)."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


class MemoryWatch:
    """Whether a larger frame size is likely to fit in memory before its first frame runs.

    Every contender keeps a state (and its library its buffers) at every size, so the process
    grows with each size it warms up; past what the machine has, the kernel kills it with no
    word. The growth of the process's peak memory (VmHWM) while the last size warmed up,
    scaled by pixels and by SAFETY, predicts the next size's; the first size warmed is not
    used, as it also pays the one-off costs (compiled kernels, thread pools, caches). Linux
    only (/proc); where the readings are missing, every size is let through.
    """

    HEADROOM = 0.9  # of the memory available
    # The timed rounds take more than the warm-up frame: with every demo and --eager, the
    # peak went from 8.0 GiB after the 720p warm-up (6.8 GiB above 320x240's) to 11.1 GiB.
    SAFETY = 1.5

    def __init__(
        self,
        peak: Callable[[], int | None] = lambda: _proc_kib("/proc/self/status", "VmHWM"),
        current: Callable[[], int | None] = lambda: _proc_kib("/proc/self/status", "VmRSS"),
        available: Callable[[], int | None] = lambda: _proc_kib("/proc/meminfo", "MemAvailable"),
    ) -> None:
        self.peak, self.current, self.available = peak, current, available
        self.warmed: list[tuple[str, int, int | None]] = []  # (label, pixels, peak after)

    def done(self, label: str, pixels: int) -> None:
        """`label` (pixels) has warmed up."""
        self.warmed.append((label, pixels, self.peak()))

    def refuse(self, label: str, pixels: int) -> str | None:
        """Why `label` (pixels) should not be timed, or None."""
        if len(self.warmed) < 2:
            return None
        (_, _, before), (last, last_pixels, after) = self.warmed[-2:]
        peak, current, available = self.peak(), self.current(), self.available()
        if None in (before, after, peak, current, available):
            return None
        grown = max(after - before, 0)
        need = self.SAFETY * grown * pixels / last_pixels
        if (peak - current) + need <= self.HEADROOM * available:  # back to the peak, then up
            return None
        return (
            f"{label} not timed: warming up {last} raised this process's peak memory by "
            f"{grown / GIB:.1f} GiB, so {label} would need about {need / GIB:.1f} GiB more, "
            f"and {available / GIB:.1f} GiB are available; time fewer models or sizes"
        )


def speed(
    contenders: Sequence[Contender],
    sizes: Iterable[tuple[int, int]],
    repeats: int = 5,
    frames: int = 4,
    progress: Callable[[str], None] = lambda _msg: None,
    memory: MemoryWatch | None = None,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Per size (H, W): every contender's times and their summary; and the sizes left out,
    with why ([{"size", "reason"}]). All sizes are timed in the same interleaved rounds
    (`repeats` of them, `frames_per_round` frames per size), each contender at each size with
    a state of its own (`Contender.fresh`): a machine whose speed drifts during the run slows
    every size alike, so times per pixel compare across sizes. The sizes warm up one after
    another, smallest first; one that `memory` (default: a `MemoryWatch`) says would not fit
    is left out, and every larger one with it."""
    sizes = list(sizes)
    memory = MemoryWatch() if memory is None else memory
    buffers = sorted({b for c in contenders for b in c.buffers})
    under_way = _Rounds(SETTLE_S)
    indices: dict[int, range] = {}
    skipped: list[dict[str, Any]] = []
    progress(", ".join(f"{w}x{h}" for h, w in sizes))
    for k in sorted(range(len(sizes)), key=lambda k: sizes[k][0] * sizes[k][1]):
        h, w = sizes[k]
        label = f"{w}x{h}"
        why = (
            memory.refuse(label, h * w)
            if not skipped
            else f"{label} not timed: a smaller size was not"
        )
        if why:
            skipped.append({"size": [h, w], "reason": why})
            continue
        seq = synthetic_frames(buffers, frames, h, w)
        slots = [
            Slot((h, w, c.name), c if k == 0 or c.fresh is None else c.fresh(), seq,
                 frames_per_round(h, w))
            for c in contenders
        ]  # fmt: skip
        indices[k] = under_way.add(slots)
        progress(f"warming up {label}")
        under_way.play(indices[k], timed=False)
        memory.done(label, h * w)
    order = [i for k in range(len(sizes)) if k in indices for i in indices[k]]
    for r in range(repeats):
        progress(f"round {r + 1} of {repeats}")
        under_way.play(order, timed=True)
    rows = []
    for k, (h, w) in enumerate(sizes):
        if k not in indices:
            continue
        size_times = {c.name: under_way.times[(h, w, c.name)] for c in contenders}
        rows.append(
            {
                "size": [h, w],
                "repeats": repeats * frames_per_round(h, w),
                "times_ms": size_times,
                "summary": {n: summarize_times(t, h * w) for n, t in size_times.items()},
            }
        )
    return rows, skipped


# the scores of `quality`, each per sequence and as a mean over the sequences
SCORES = ("psnr", "ssim", "smape", "relmse", "trmae")


def load_sequences(folders: Sequence[Path], buffers: Sequence[str]) -> list[tuple]:
    """(name, frames, references, cut indices) of each folder with references (default: the
    bundled ones); frames hold `buffers` (a per-sample model's `samples`: S = 1 from the pixel
    means when the files have no sample layers); the cuts from its meta.json (a rendered one)."""
    from rtdenoise.shipped import sample_sequences

    from .frames import (
        find_frames,
        frame_number,
        group_shots,
        match_references,
        read_frame,
        read_reference,
        shot_cuts,
    )

    folders = list(folders) or sample_sequences()
    # named as denoise-run names shots: validation/seq_000 and sequences/seq_000 stay two
    names = [name for name, _ in group_shots(folders)]
    out = []
    for name, folder in zip(names, folders, strict=True):
        paths = find_frames(folder)
        refs = match_references(paths)
        if not all(refs):
            raise InputError(f"{folder}: every frame needs a reference ref_NNNN.exr for quality")
        frames = [read_frame(p, buffers=list(buffers)).buffers for p in paths]
        cuts = shot_cuts(folder)
        starts = [i for i, p in enumerate(paths) if i and frame_number(p) in cuts]
        out.append((name, frames, [read_reference(r) for r in refs], starts))
    return out


def walk(contender: Contender, frames: Sequence[Frame], cuts: Collection[int] = ()) -> Iterator:
    """The contender's output (C, H, W float32) on each frame of one sequence, from a reset, its
    state carried; `cuts`: the indices of the frames that start a new shot (its `cut` before)."""
    cuts = set(cuts)
    contender.reset()
    for i, frame in enumerate(frames):
        if i in cuts:
            (contender.cut or contender.reset)()
        yield np.asarray(contender.denoise(contender.prepare(frame)), np.float32)


def quality(
    contenders: Sequence[Contender],
    sequences: Sequence[tuple],
    progress: Callable[[str], None] = lambda _msg: None,
) -> dict[str, dict[str, Any]]:
    """Per contender: the SCORES (PSNR pooled, SSIM, SMAPE and relMSE averaged over the frames,
    TRMAE over the sequence) per sequence (frames with state) and their means.
    sequences: (name, frames, references) or (name, frames, references, cuts), cuts the
    indices of the frames that start a new shot (the contender's `cut` runs before them)."""
    out: dict[str, dict[str, Any]] = {}
    for c in contenders:
        progress(f"quality: {c.name}")
        per_seq = {}
        for name, frames, references, *rest in sequences:
            metrics = SequenceMetrics()
            outputs = walk(c, frames, rest[0] if rest else ())
            for output, ref in zip(outputs, references, strict=True):
                metrics.add(output, ref)
            s = metrics.summary()
            per_seq[name] = {k: s[k] for k in SCORES}
        out[c.name] = {
            "sequences": per_seq,
            "mean": {k: float(np.mean([v[k] for v in per_seq.values()])) for k in SCORES},
        }
    return out


def noisy_quality(sequences: Sequence[tuple]) -> dict[str, Any]:
    """The same scores for the noisy input itself (the baseline every denoiser must beat)."""
    identity = Contender("noisy input", lambda f: f["color"], lambda: None, ("color",))
    return quality([identity], sequences)["noisy input"]
