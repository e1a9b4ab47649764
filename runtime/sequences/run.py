"""One sequence through a backend: plan, read, process, write, score (`denoise-run`'s job).

Torch-free. The caller presents: it hears of progress and warnings through callbacks and
formats the report (a dict, the metrics JSON of one sequence) as it likes.

Per frame the lean path does: read only the channels the backend needs (resolved once per
sequence from the headers), one NaN/Inf pass per buffer (in the reader; a `Denoiser` guards
every buffer again: NaN/Inf, ranges and outliers), process, one NaN/Inf
check of the output, quantise once (half by default) and write that array; the float32 view of
exactly that array is what is scored and previewed.

Before the first frame: every header, the references, the output paths (no existing output
replaced unless `overwrite`; kept with `resume`) and the output folder's writability are
checked, and temp files a killed run left for these outputs are removed. Frame-number gaps
reset the history. docs/reliability.md has every case.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..contract import SAMPLES
from ..errors import InputError
from ..guard import nonfinite_pixels
from .atomic import check_writable, temp_files_of
from .backend import Backend
from .exr import (
    Window,
    pixel_limit,
    read_exr,
    read_exr_attributes,
    read_exr_header,
    read_exr_windows,
)
from .frames import (
    frame_number,
    match_references,
    plan_sequence,
    quantize_output,
    reference_pixels,
    scan_reference,
    shot_cuts,
    write_rgb,
)
from .layouts import Layout, get_layout
from .metrics import SequenceMetrics
from .preview import write_png
from .provenance import mismatch, record
from .samples import sample_features_of

METRIC_KEYS = ("psnr", "ssim", "smape", "relmse")
MAX_WARNINGS = 10  # NaN/Inf and guard warnings per sequence, then one line with the rest
# --resume re-runs up to this many frames before the first frame to denoise: the history of
# the accumulating models keeps 0.8 ** 16 = 2.8 % of what came before (exact when fewer
# frames precede it since the last reset).
RESUME_WARMUP = 16


@dataclass
class Job:
    """One sequence to denoise."""

    name: str
    frames: list[Path]
    reference: str | None  # reference spec, None = ref_NNNN.exr beside each frame
    out_dir: Path


def check_out_dir(out_dir: Path) -> None:
    """InputError when the output folder exists as a file or cannot be written."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: output folder is a file")
    check_writable(out_dir / "frame.exr")


def plan_outputs(job: Job, references: Sequence[Path | None], preview: bool) -> list[Path]:
    """OUT/<input name> for every frame; refuse duplicates and overwriting an input."""
    outputs = [job.out_dir / p.name for p in job.frames]
    seen: dict[Path, Path] = {}
    inputs = {p.resolve() for p in job.frames} | {r.resolve() for r in references if r}
    for src, out in zip(job.frames, outputs, strict=True):
        if out in seen:
            raise InputError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
        for t in _targets(out, preview):
            if t.resolve() in inputs:
                raise InputError(f"{t}: writing the output would overwrite an input file")
    return outputs


def _targets(out: Path, preview: bool) -> list[Path]:
    """The files written for one frame."""
    return [out] + ([out.with_suffix(".png")] if preview else [])


def frames_done(
    outputs: Sequence[Path], preview: bool, *, overwrite: bool, resume: bool
) -> list[bool]:
    """Which frames are already done (all their files exist) and are kept (`resume`).

    InputError when some output exists and neither `overwrite` nor `resume` says what to do
    with it: outputs never replace existing files by surprise (docs/reliability.md).
    """
    if overwrite and resume:
        raise InputError("--overwrite and --resume exclude each other")
    existing = [t for out in outputs for t in _targets(out, preview) if t.exists()]
    if existing and not (overwrite or resume):
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise InputError(
            f"{existing[0]}: output exists{more}; --overwrite replaces existing outputs, "
            "--resume keeps them and denoises the frames that have none"
        )
    if not resume:
        return [False] * len(outputs)
    return [all(t.exists() for t in _targets(out, preview)) for out in outputs]


def remove_stale_temps(outputs: Sequence[Path], preview: bool) -> int:
    """Remove the temp files a killed run left for these outputs; how many there were."""
    stale = [
        t for out in outputs for target in _targets(out, preview) for t in temp_files_of(target)
    ]
    for t in stale:
        t.unlink(missing_ok=True)
    return len(stale)


def gap_before(frames: Sequence[Path], i: int) -> int | None:
    """The number of frames missing between frame i - 1 and frame i (by frame number), or
    None when they are consecutive (or unnumbered)."""
    if i == 0:
        return None
    a, b = frame_number(frames[i - 1]), frame_number(frames[i])
    if a is None or b is None or b == a + 1:
        return None
    return b - a - 1


def _nothing(*_: object) -> None:
    pass


def _nonfinite_message(pixels: int, buffers: Sequence[str], bad_out: int) -> str:
    parts = []
    if pixels:
        parts.append(f"{pixels} pixels with NaN/Inf in {', '.join(buffers)} replaced")
    if bad_out:
        parts.append(f"{bad_out} non-finite output pixels replaced by 0")
    return "; ".join(parts)


def unreadable_output(path: Path, size: tuple[int, int]) -> str | None:
    """Why an existing output cannot be kept by --resume (its header, its R, G, B at the
    sequence's (height, width), its pixels decoded), or None when it reads. A file renamed
    before its data reached the disk (power loss) is empty or truncated."""
    try:
        sizes = read_exr_header(path)
        absent = [c for c in "RGB" if c not in sizes]
        if absent:
            return f"no channel {absent[0]!r}"
        odd = next((c for c in "RGB" if sizes[c] != tuple(size)), None)
        if odd is not None:
            (h, w), (eh, ew) = sizes[odd], size
            return f"channel {odd!r} is {w}x{h}, the sequence is {ew}x{eh}"
        read_exr(path, list("RGB"))
    except InputError as exc:
        return str(exc).removeprefix(f"{path}: ")
    return None


def _box(window: Window) -> str:
    (x0, y0), (x1, y1) = window
    return f"({x0},{y0})-({x1},{y1})"


def _read_rgb(path: Path) -> np.ndarray:
    """R,G,B of an output file as float32 (3, H, W)."""
    ch = read_exr(path, list("RGB"))
    return np.stack([ch[c] for c in "RGB"])


def run_sequence(
    job: Job,
    backend: Backend,
    layout: Layout | str,
    overrides: dict[str, str],
    *,
    half: bool = True,
    preview: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    on_frame: Callable[[], None] = _nothing,
    on_warning: Callable[[str], None] = _nothing,
    reading: Callable[[], AbstractContextManager[Any]] = nullcontext,
    max_pixels: int | None = None,
) -> dict[str, Any]:
    """Denoise one sequence; returns its report (the metrics JSON of one sequence).

    max_pixels: every file's header is refused above this many pixels before any decode
        (None: `exr.DEFAULT_MAX_PIXELS`); a MemoryError while a frame is read, denoised or
        written becomes an InputError naming the file and the frame size.

    Checks every header, the references and the output paths before writing anything.
    overwrite: replace existing outputs; resume: keep them (those frames are scored from
        their files) and denoise the others, after re-running up to `RESUME_WARMUP` frames
        before each to rebuild the history; neither: InputError if an output exists.
        Every output records its model, options and the rtdenoise version in its header
        (runtime/sequences/provenance.py); resume refuses (InputError naming the file and
        what differs) a kept output of another model or other options.
    A gap in the frame numbers (2 -> 4) resets the history, with a warning, and breaks the
    temporal metrics' chain.
    on_frame: called after each frame is written (or kept) and scored.
    on_warning: one-line warnings (frames without reference, NaN/Inf replaced, guard, gaps).
    reading: a context manager factory wrapped around every file read (the CLI silences
        OpenEXR's own prints on the process's stdout/stderr with it).
    """
    with pixel_limit(max_pixels):
        return _run_sequence(
            job,
            backend,
            layout,
            overrides,
            half=half,
            preview=preview,
            overwrite=overwrite,
            resume=resume,
            on_frame=on_frame,
            on_warning=on_warning,
            reading=reading,
        )


def _run_sequence(
    job: Job,
    backend: Backend,
    layout: Layout | str,
    overrides: dict[str, str],
    *,
    half: bool,
    preview: bool,
    overwrite: bool,
    resume: bool,
    on_frame: Callable[[], None],
    on_warning: Callable[[str], None],
    reading: Callable[[], AbstractContextManager[Any]],
) -> dict[str, Any]:
    check_out_dir(job.out_dir)
    needed = getattr(backend, "required_buffers", None)
    per_sample = needed is not None and SAMPLES in needed  # features from the model's config
    features = sample_features_of(getattr(backend, "config", {})) if per_sample else None
    with reading():
        plan = plan_sequence(
            job.frames, layout, overrides, buffers=needed, sample_features=features
        )
    size = plan.size
    references = match_references(job.frames, job.reference)
    if job.reference is not None and not any(references):
        raise InputError(f"{job.reference}: no reference matches the frame numbers of {job.name}")
    missing_refs = sum(r is None for r in references)
    if any(references) and missing_refs:
        on_warning(f"{job.name}: {missing_refs} of {len(job.frames)} frames have no reference")
    with reading():
        for ref in references:
            if ref is not None:
                scan_reference(ref, layout, expect_size=size)
    outputs = plan_outputs(job, references, preview)
    done = frames_done(outputs, preview, overwrite=overwrite, resume=resume)
    for i, out_path in enumerate(outputs):
        if done[i]:
            with reading():
                problem = unreadable_output(out_path, size)
            if problem:
                done[i] = False
                on_warning(f"{out_path}: kept output does not read ({problem}): denoised again")
    made_by = record(
        backend, get_layout(layout) if isinstance(layout, str) else layout, overrides, half
    )
    for i, out_path in enumerate(outputs):
        if done[i]:
            with reading():
                why = mismatch(read_exr_attributes(out_path, "rtdenoise."), made_by)
            if why:
                raise InputError(
                    f"{out_path}: --resume would mix outputs: {why}; rerun with the options "
                    "that made it, --overwrite to replace the outputs, or another -o folder"
                )
    stale = remove_stale_temps(outputs, preview)
    if stale:
        on_warning(f"{job.out_dir}: removed {stale} temp files an interrupted run left")

    scored_out, scored_in = SequenceMetrics(), SequenceMetrics()
    rows: list[dict[str, Any]] = []
    times: dict[str, list[float]] = {"read": [], "denoise": [], "write": []}
    warnings = 0
    previous_scored = False
    fed = -1  # index of the last frame the backend has seen (its history ends there)
    segment = 0  # index of the first frame after the last gap
    backend.reset()
    cuts = {c for folder in {p.parent for p in job.frames} for c in shot_cuts(folder)}
    current = job.frames[0] if job.frames else job.out_dir
    window = None  # the previous frame's data window
    try:
        frames = zip(job.frames, references, outputs, strict=True)
        for i, (path, ref, out_path) in enumerate(frames):
            current = path
            gap = gap_before(job.frames, i)
            if i and not gap and frame_number(path) in cuts:  # a camera cut (meta.json)
                segment = i
                backend.reset()
            if gap:
                segment = i
                backend.reset()
                on_warning(
                    f"{path}: {gap} frame{'s' * (gap > 1)} missing before it (frame numbers "
                    f"{frame_number(job.frames[i - 1])} -> {frame_number(path)}): history reset"
                )
            with reading():
                windows = read_exr_windows(path)
            if window is not None and windows[0] != window and not gap:
                segment = i  # the pixels moved on the canvas: the history is not theirs
                backend.reset()
                on_warning(
                    f"{path}: data window {_box(windows[0])} differs from the previous "
                    f"frame's {_box(window)}: history reset"
                )
            window = windows[0]
            if done[i] and ref is None:
                rows.append(_row(i, path, out_path, None, skipped=True))
                on_frame()
                continue
            if not done[i] and fed != i - 1 and i > segment:  # frames before it were kept:
                backend.reset()  # rebuild the history from them (not timed, not written)
                for j in range(max(segment, i - RESUME_WARMUP), i):
                    with reading():
                        warm = plan.read(job.frames[j], index=j)
                    backend.process(warm.buffers)
            t0 = time.perf_counter()
            with reading():
                frame = plan.read(path, index=i)
            t1 = time.perf_counter()
            row = _row(i, path, out_path, ref, skipped=done[i], frame=frame)
            if done[i]:  # kept from an earlier run: score the file
                with reading():
                    view = _read_rgb(out_path)
            else:
                out = np.asarray(backend.process(frame.buffers), dtype=np.float32)
                fed = i
                if out.ndim == 4 and out.shape[0] == 1:
                    out = out[0]
                if out.shape != (3, *size):
                    raise RuntimeError(
                        f"{path}: the model returned shape {out.shape}, not (3, *{size})"
                    )
                bad_mask = nonfinite_pixels(out)
                bad_out = 0 if bad_mask is None else int(bad_mask.sum())
                if bad_out:  # a copy: the array may be the backend's own
                    out = np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
                t2 = time.perf_counter()
                written = quantize_output(out, half)
                write_rgb(out_path, written, half, windows, made_by)
                # Score and preview what was written: the float32 view of the stored half floats.
                scored = half and (preview or ref is not None)
                view = written.astype(np.float32) if scored else written
                if preview:
                    write_png(out_path.with_suffix(".png"), view)
                t3 = time.perf_counter()
                for key, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2), strict=True):
                    times[key].append(dt * 1e3)
                guard = getattr(backend, "last_guard", None)
                guard_text = guard.summary() if guard is not None else ""
                row["reset"] = getattr(guard, "reset", None)
                row["guard"] = guard_text or None
                message = "; ".join(
                    m
                    for m in (
                        _nonfinite_message(frame.nonfinite, frame.nonfinite_buffers, bad_out),
                        guard_text,
                    )
                    if m
                )
                if message:
                    warnings += 1
                    if warnings <= MAX_WARNINGS:
                        on_warning(f"{path}: {message}")
            consecutive = previous_scored and not gap
            target = None
            if ref is not None:
                with reading():
                    target, bad_ref = reference_pixels(ref, layout, expect_size=size)
                if bad_ref:
                    on_warning(f"{ref}: {bad_ref} reference pixels are NaN/Inf: frame not scored")
                    row["reference_nonfinite"], target = bad_ref, None
            if target is not None:
                row.update(scored_out.add(view, target, consecutive=consecutive))
                color = frame.buffers["color"]
                row["input"] = scored_in.add(color, target, consecutive=consecutive)
            previous_scored = target is not None
            rows.append(row)
            on_frame()
    except MemoryError:  # a 24 GiB machine shared by jobs: say which frame, not a traceback
        raise InputError(
            f"{current}: out of memory denoising its {size[1]}x{size[0]} frame "
            f"({size[0] * size[1]} pixels); lower --max-pixels, run fewer jobs at once or "
            "free memory (the frames before it are complete files: rerun with --resume)"
        ) from None
    if warnings > MAX_WARNINGS:
        on_warning(
            f"{job.name}: {warnings - MAX_WARNINGS} more frames had input fixed by the guard"
        )

    out_summary, in_summary = scored_out.summary(), scored_in.summary()
    return {
        "name": job.name,
        "size": list(size),
        "frames": rows,
        "mean": {k: out_summary[k] for k in METRIC_KEYS} if out_summary else None,
        "trmae": out_summary.get("trmae"),
        "input": in_summary or None,
        "nonfinite": sum(r["nonfinite"] or 0 for r in rows),
        "skipped": sum(r["skipped"] for r in rows),
        "timing_ms": {k: statistics.median(v) if v else None for k, v in times.items()},
        # how the custom ops ran: "native-cpp", "native", "extensions", "" (portable bodies)
        "kernels": getattr(backend, "bridge", None),
        # which conv forms loaded (docs/contract.md, "Layout forms"): "nchwc16", "plain", ""
        "layout": getattr(backend, "layout", None),
    }


def online_summary(backend: Backend) -> dict[str, Any] | None:
    """Steps taken and last loss of a model that learns while it runs (None otherwise)."""
    spec = getattr(backend, "online", None)
    if not spec:
        return None
    summary: dict[str, Any] = {"learn": backend.learn, "learn_every": backend.learn_every}
    for key in ("step", "loss"):
        if spec.get(key):
            summary[key] = float(backend.state_value(spec[key]).ravel()[0])
    return summary


def _row(
    i: int, path: Path, out_path: Path, ref: Path | None, *, skipped: bool, frame: Any = None
) -> dict[str, Any]:
    """A report row without metrics (filled in when the frame is scored)."""
    n = frame_number(path)
    row: dict[str, Any] = {
        "index": frame.index if frame is not None else (n if n is not None else i),
        "file": str(path),
        "output": str(out_path),
        "reference": str(ref) if ref else None,
        "nonfinite": frame.nonfinite if frame is not None else None,
        "skipped": skipped,
        "reset": None,
        "guard": None,
        "input": None,
    }
    row.update(dict.fromkeys(METRIC_KEYS))
    return row


__all__ = [
    "METRIC_KEYS",
    "RESUME_WARMUP",
    "Job",
    "check_out_dir",
    "frames_done",
    "gap_before",
    "online_summary",
    "plan_outputs",
    "remove_stale_temps",
    "run_sequence",
]
