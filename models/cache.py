"""A memory-mapped cache of training sequences, for training sets larger than memory.

Each sequence folder is read once (models.data.load_sequence) and written as one .npy file per
buffer plus `reference.npy` into `<cache>/<folder name>-<key>/`; later runs open them with
`np.load(mmap_mode="r")`, so a step reads (through the page cache) only the rows of its crops
and the process's own memory stays flat however many sequences there are. Arrays are stored as
float16 when that is exact (the renderer writes half-float EXR), else float32 (e.g. a
background depth of 1e10, or full-float files); the clip sampler converts each crop to float32.

The key hashes the folder's resolved path, the name, size and modification time of every file
in it, the buffers, the per-sample features and (for any layout but `canonical`) the layout
file's name and content, so an edited or re-rendered sequence is
converted again. A conversion is written into a temporary folder and renamed into place, so an
interrupted run leaves no half-written entry and concurrent runs do not read one.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.sequences.frames import shot_cuts
from rtdenoise.runtime.sequences.layouts import Layout, get_layout, layout_fingerprint

from .data import SequenceData, load_sequence

CACHE_VERSION = 1
_DONE = "sequence.json"


def cache_key(
    folder: str | os.PathLike,
    buffers: Sequence[str],
    sample_features: Sequence[str] | None,
    layout: Layout | str = "canonical",
) -> str:
    """16 hex digits naming what a cache entry was made from (see the module docstring)."""
    folder = Path(folder).resolve()
    files = sorted(
        (p.name, st.st_size, st.st_mtime_ns)
        for p in folder.iterdir()
        if p.is_file() and (st := p.stat())
    )
    features = list(sample_features or ()) if SAMPLES in buffers else []
    parts: list = [CACHE_VERSION, str(folder), files, list(buffers), features]
    layout = get_layout(layout) if isinstance(layout, str) else layout
    if layout.name != "canonical":  # canonical entries keep the keys they always had
        parts.append(layout_fingerprint(layout))
    blob = json.dumps(parts)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def compact(arr: np.ndarray) -> np.ndarray:
    """`arr` as float16 if that round-trips exactly, else as float32."""
    with np.errstate(over="ignore"):  # beyond 65504: inf, not equal, kept as float32
        half = arr.astype(np.float16)
    return half if np.array_equal(half.astype(arr.dtype), arr) else arr.astype(np.float32)


def _open(entry: Path, folder: Path, buffers: Sequence[str]) -> SequenceData:
    return SequenceData(
        name=folder.name,
        buffers={b: np.load(entry / f"{b}.npy", mmap_mode="r") for b in buffers},
        reference=np.load(entry / "reference.npy", mmap_mode="r"),
        cuts=shot_cuts(folder),
    )


def cached_sequence(
    folder: str | os.PathLike,
    buffers: Sequence[str],
    sample_features: Sequence[str] | None,
    cache: str | os.PathLike,
    layout: Layout | str = "canonical",
) -> SequenceData:
    """The sequence at `folder` (read through `layout`) memory-mapped from `cache`, converted
    first if needed."""
    folder, cache = Path(folder), Path(cache)
    entry = cache / f"{folder.name}-{cache_key(folder, buffers, sample_features, layout)}"
    if (entry / _DONE).is_file():
        return _open(entry, folder, buffers)
    seq = load_sequence(folder, buffers, sample_features, layout)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{entry.name}.", dir=cache))
    try:
        for name, arr in seq.buffers.items():
            np.save(tmp / f"{name}.npy", compact(arr))
        np.save(tmp / "reference.npy", compact(seq.reference))
        (tmp / _DONE).write_text(json.dumps({"source": str(folder.resolve())}) + "\n")
        if entry.exists() and not (entry / _DONE).is_file():  # left by an older, broken run
            shutil.rmtree(entry, ignore_errors=True)
        try:
            os.replace(tmp, entry)
        except OSError:  # another run wrote the same entry meanwhile: use that one
            if not (entry / _DONE).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return _open(entry, folder, buffers)


__all__ = ["CACHE_VERSION", "cache_key", "cached_sequence", "compact"]
