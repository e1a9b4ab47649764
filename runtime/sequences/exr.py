"""Read and write EXR files with OpenEXR's own Python bindings.

Channels are plain 2-D arrays keyed by their full EXR channel name
("R", "albedo.G", "ViewLayer.Denoising Albedo.R"). Multi-part files (Blender 5
multilayer) are flattened: every part's channels go into one dict. A channel name that
several parts use (parts "rgb" and "albedo" each with R, G, B) is read as
`<part name>.<channel>` ("rgb.R", "albedo.R"), never one part silently over another.
Writes are atomic: a temp file in the target folder, then a rename.

The bindings (OpenEXR 3.x) always decode every channel of a file: they have no way to read
a subset. `read_exr(path, channels=...)` therefore saves the rest of the work only: the
channels not asked for are never converted or copied.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import InputError
from .atomic import atomic_path


def _part_name(part: object) -> str | None:
    try:
        name = part.name()  # type: ignore[attr-defined]
    except Exception:
        return None
    return name or None


def qualified_names(path: Path, parts: list[tuple[str | None, list[str]]]) -> list[dict[str, str]]:
    """Per part, channel name -> the name it is read as: itself, or `<part name>.<channel>`
    when several parts use that name. InputError if that cannot make the names unique."""
    count: dict[str, int] = {}
    for _, names in parts:
        for n in names:
            count[n] = count.get(n, 0) + 1
    result: list[dict[str, str]] = []
    seen: dict[str, int] = {}
    for i, (part, names) in enumerate(parts):
        mapping = {}
        for n in names:
            full = n
            if count[n] > 1:
                if not part:
                    raise InputError(
                        f"{path}: channel {n!r} is in {count[n]} parts and part {i} has no name"
                    )
                full = f"{part}.{n}"
            if full in seen:
                raise InputError(
                    f"{path}: channel {full!r} is in parts {seen[full]} and {i}; rename the "
                    "parts or their channels"
                )
            seen[full] = i
            mapping[n] = full
        result.append(mapping)
    return result


def _decode(path: Path) -> dict[str, np.ndarray]:
    """Every channel the bindings decode, as 2-D arrays in the file's own pixel type."""
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            parts = [(_part_name(p), list(p.channels)) for p in exr.parts]
            names = qualified_names(path, parts)
            channels: dict[str, np.ndarray] = {}
            for part, mapping in zip(exr.parts, names, strict=True):
                for name, channel in part.channels.items():
                    pixels = np.asarray(channel.pixels)
                    if pixels.ndim != 2:
                        raise InputError(f"{path}: channel {name!r} has shape {pixels.shape}")
                    channels[mapping[name]] = pixels
    except InputError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError/OSError for truncated/corrupt files
        raise InputError(f"{path}: cannot read EXR ({exc})") from exc
    return channels


def _lost_error(path: Path, lost: list[str]) -> InputError:
    return InputError(
        f"{path}: cannot read EXR (truncated or corrupt: no pixel data for {len(lost)} "
        f"channels, e.g. {lost[0]!r})"
    )


def read_exr(
    path: str | os.PathLike,
    channels: Collection[str] | None = None,
    *,
    dtype: type | None = np.float32,
) -> dict[str, np.ndarray]:
    """Channels of an EXR file (every part) as contiguous 2-D arrays.

    channels: only these (InputError naming the file and the first absent channel); None: all.
    dtype: convert to this type (default float32); None keeps the file's type (float16 for
        half channels) without a copy, for callers that convert while stacking.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    decoded = _decode(path)
    if channels is None:
        # OpenEXR 3.5 drops the parts whose pixels it cannot read (truncated file) with only
        # a printed warning: compare with the channels the headers list.
        lost = sorted(set(read_exr_header(path)) - set(decoded))
        if lost:
            raise _lost_error(path, lost)
        if not decoded:
            raise InputError(f"{path}: EXR file has no channels")
        names: Collection[str] = decoded
    else:
        absent = [n for n in channels if n not in decoded]
        if absent:  # the header tells a dropped (truncated) part from a channel never there
            listed = read_exr_header(path)
            lost = [n for n in absent if n in listed]
            if lost:
                raise _lost_error(path, lost)
            shown = sorted(listed)
            more = f", ... (+{len(shown) - 40} more)" if len(shown) > 40 else ""
            raise InputError(
                f"{path}: no channel {absent[0]!r}; channels present: {', '.join(shown[:40])}{more}"
            )
        names = channels
    if dtype is None:
        return {n: np.ascontiguousarray(decoded[n]) for n in names}
    return {n: np.ascontiguousarray(decoded[n], dtype=dtype) for n in names}


def read_exr_header(path: str | os.PathLike) -> dict[str, tuple[int, int]]:
    """Channel name -> (height, width) of every part, reading headers only (no pixels)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True, header_only=True) as exr:
            parts = [(_part_name(p), [c.name for c in p.header["channels"]]) for p in exr.parts]
            names = qualified_names(path, parts)
            sizes: dict[str, tuple[int, int]] = {}
            for part, mapping in zip(exr.parts, names, strict=True):
                (x0, y0), (x1, y1) = (tuple(int(v) for v in c) for c in part.header["dataWindow"])
                for channel in part.header["channels"]:
                    sizes[mapping[channel.name]] = (y1 - y0 + 1, x1 - x0 + 1)
    except InputError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError for truncated/corrupt headers
        raise InputError(f"{path}: cannot read EXR ({exc})") from exc
    if not sizes:
        raise InputError(f"{path}: EXR file has no channels")
    return sizes


def write_exr(
    path: str | os.PathLike,
    channels: dict[str, np.ndarray],
    *,
    half: bool = True,
) -> Path:
    """Write 2-D channels to a single-part, ZIP-compressed EXR, atomically.

    `half=True` stores float16 (the default for denoised output), else float32. Arrays
    already of that type and contiguous are written as they are (no conversion, no copy).
    """
    path = Path(path)
    if not channels:
        raise ValueError("write_exr: no channels given")
    dtype = np.float16 if half else np.float32
    shapes = {name: np.shape(a) for name, a in channels.items()}
    first = next(iter(shapes.values()))
    if len(first) != 2 or any(s != first for s in shapes.values()):
        raise ValueError(f"write_exr: channels must be 2-D and of one size, got {shapes}")
    # OpenEXR writes non-contiguous arrays wrong without an error: always pass contiguous ones.
    data = {name: np.ascontiguousarray(a, dtype=dtype) for name, a in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, data) as exr:
        exr.write(str(tmp))
    return path
