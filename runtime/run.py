"""One sequence through a backend: plan, read, process, write, score (`denoise-run`'s job).

Torch-free. The caller presents: it hears of progress and warnings through callbacks and
formats the report (a dict, the metrics JSON of one sequence) as it likes.

Per frame the lean path does: read only the channels the backend needs (resolved once per
sequence from the headers), one NaN/Inf pass per buffer (in the reader; the backend is told
with `assume_finite=True`), process, one NaN/Inf check of the output, quantise once (half by
default) and write that array; the float32 view of exactly that array is what is scored
and previewed.
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

from .backend import Backend
from .contract import SAMPLES
from .errors import InputError
from .layouts import Layout
from .metrics import SequenceMetrics
from .preview import write_png
from .samples import sample_features_of
from .sequence import (
    match_references,
    nonfinite_pixels,
    plan_sequence,
    quantize_output,
    read_reference,
    scan_reference,
    write_rgb,
)

METRIC_KEYS = ("psnr", "ssim", "smape", "relmse")
MAX_WARNINGS = 10  # NaN/Inf warnings per sequence, then one line with the rest


@dataclass
class Job:
    """One sequence to denoise."""

    name: str
    frames: list[Path]
    reference: str | None  # reference spec, None = ref_NNNN.exr beside each frame
    out_dir: Path


def check_out_dir(out_dir: Path) -> None:
    """InputError when the output folder exists as a file."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: output folder is a file")


def plan_outputs(job: Job, references: Sequence[Path | None], preview: bool) -> list[Path]:
    """OUT/<input name> for every frame; refuse duplicates and overwriting an input."""
    outputs = [job.out_dir / p.name for p in job.frames]
    seen: dict[Path, Path] = {}
    inputs = {p.resolve() for p in job.frames} | {r.resolve() for r in references if r}
    for src, out in zip(job.frames, outputs, strict=True):
        if out in seen:
            raise InputError(f"{src} and {seen[out]} would both be written to {out}")
        seen[out] = src
        targets = [out] + ([out.with_suffix(".png")] if preview else [])
        for t in targets:
            if t.resolve() in inputs:
                raise InputError(f"{t}: writing the output would overwrite an input file")
    return outputs


def _nothing(*_: object) -> None:
    pass


def _nonfinite_message(pixels: int, buffers: Sequence[str], bad_out: int) -> str:
    parts = []
    if pixels:
        parts.append(f"{pixels} pixels with NaN/Inf in {', '.join(buffers)} replaced by 0")
    if bad_out:
        parts.append(f"{bad_out} non-finite output pixels replaced by 0")
    return "; ".join(parts)


def run_sequence(
    job: Job,
    backend: Backend,
    layout: Layout | str,
    overrides: dict[str, str],
    *,
    half: bool = True,
    preview: bool = False,
    on_frame: Callable[[], None] = _nothing,
    on_warning: Callable[[str], None] = _nothing,
    reading: Callable[[], AbstractContextManager[Any]] = nullcontext,
) -> dict[str, Any]:
    """Denoise one sequence; returns its report (the metrics JSON of one sequence).

    Checks every header, the references and the output paths before writing anything.
    on_frame: called after each frame is written and scored.
    on_warning: one-line warnings (frames without reference, NaN/Inf replaced).
    reading: a context manager factory wrapped around every file read (the CLI silences
        OpenEXR's own prints on the process's stdout/stderr with it).
    """
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

    scored_out, scored_in = SequenceMetrics(), SequenceMetrics()
    rows: list[dict[str, Any]] = []
    times: dict[str, list[float]] = {"read": [], "denoise": [], "write": []}
    warnings = 0
    previous_scored = False
    backend.reset()
    for i, (path, ref, out_path) in enumerate(zip(job.frames, references, outputs, strict=True)):
        t0 = time.perf_counter()
        with reading():
            frame = plan.read(path, index=i)
        t1 = time.perf_counter()
        out = np.asarray(backend.process(frame.buffers, assume_finite=True), dtype=np.float32)
        if out.ndim == 4 and out.shape[0] == 1:
            out = out[0]
        if out.shape != (3, *size):
            raise RuntimeError(f"{path}: the model returned shape {out.shape}, not (3, *{size})")
        bad_mask = nonfinite_pixels(out)
        bad_out = 0 if bad_mask is None else int(bad_mask.sum())
        if bad_out:  # a copy: the array may be the backend's own
            out = np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
        t2 = time.perf_counter()
        written = quantize_output(out, half)
        write_rgb(out_path, written, half)
        # Score and preview what was written: the float32 view of the stored half floats.
        view = written.astype(np.float32) if half and (preview or ref is not None) else written
        if preview:
            write_png(out_path.with_suffix(".png"), view)
        t3 = time.perf_counter()
        for key, dt in zip(times, (t1 - t0, t2 - t1, t3 - t2), strict=True):
            times[key].append(dt * 1e3)

        if frame.nonfinite or bad_out:
            warnings += 1
            if warnings <= MAX_WARNINGS:
                message = _nonfinite_message(frame.nonfinite, frame.nonfinite_buffers, bad_out)
                on_warning(f"{path}: {message}")
        row: dict[str, Any] = {
            "index": frame.index,
            "file": str(path),
            "output": str(out_path),
            "reference": str(ref) if ref else None,
            "nonfinite": frame.nonfinite,
        }
        if ref is not None:
            with reading():
                target = read_reference(ref, layout, expect_size=size)
            row.update(scored_out.add(view, target, consecutive=previous_scored))
            row["input"] = scored_in.add(
                frame.buffers["color"], target, consecutive=previous_scored
            )
        else:
            row.update(dict.fromkeys(METRIC_KEYS))
            row["input"] = None
        previous_scored = ref is not None
        rows.append(row)
        on_frame()
    if warnings > MAX_WARNINGS:
        on_warning(f"{job.name}: {warnings - MAX_WARNINGS} more frames had NaN/Inf values")

    out_summary, in_summary = scored_out.summary(), scored_in.summary()
    return {
        "name": job.name,
        "size": list(size),
        "frames": rows,
        "mean": {k: out_summary[k] for k in METRIC_KEYS} if out_summary else None,
        "trmae": out_summary.get("trmae"),
        "input": in_summary or None,
        "nonfinite": sum(r["nonfinite"] for r in rows),
        "timing_ms": {k: statistics.median(v) if v else None for k, v in times.items()},
    }


__all__ = ["METRIC_KEYS", "Job", "check_out_dir", "plan_outputs", "run_sequence"]
