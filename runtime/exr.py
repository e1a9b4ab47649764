"""Read and write EXR files with OpenEXR's own Python bindings.

Channels are plain 2-D float32 arrays keyed by their full EXR channel name
("R", "albedo.G", "ViewLayer.Denoising Albedo.R"). Multi-part files (Blender 5
multilayer) are flattened: every part's channels go into one dict.
Writes are atomic: a temp file in the target folder, then a rename.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR

from .atomic import atomic_path
from .errors import InputError


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All channels of an EXR file (every part), as contiguous 2-D float32 arrays."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels: dict[str, np.ndarray] = {}
            for part in exr.parts:
                for name, channel in part.channels.items():
                    pixels = np.asarray(channel.pixels)
                    if pixels.ndim != 2:
                        raise InputError(f"{path}: channel {name!r} has shape {pixels.shape}")
                    channels[name] = np.ascontiguousarray(pixels, dtype=np.float32)
    except InputError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError/OSError for truncated/corrupt files
        raise InputError(f"{path}: cannot read EXR ({exc})") from exc
    # OpenEXR 3.5 drops the parts whose pixels it cannot read (truncated file) with only a
    # printed warning: compare with the channels the headers list.
    lost = sorted(set(read_exr_header(path)) - set(channels))
    if lost:
        raise InputError(
            f"{path}: cannot read EXR (truncated or corrupt: no pixel data for {len(lost)} "
            f"channels, e.g. {lost[0]!r})"
        )
    if not channels:
        raise InputError(f"{path}: EXR file has no channels")
    return channels


def read_exr_header(path: str | os.PathLike) -> dict[str, tuple[int, int]]:
    """Channel name -> (height, width) of every part, reading headers only (no pixels)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with OpenEXR.File(str(path), separate_channels=True, header_only=True) as exr:
            sizes: dict[str, tuple[int, int]] = {}
            for part in exr.parts:
                (x0, y0), (x1, y1) = (tuple(int(v) for v in c) for c in part.header["dataWindow"])
                for channel in part.header["channels"]:
                    sizes[channel.name] = (y1 - y0 + 1, x1 - x0 + 1)
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

    `half=True` stores float16 (the default for denoised output), else float32.
    """
    path = Path(path)
    if not channels:
        raise ValueError("write_exr: no channels given")
    dtype = np.float16 if half else np.float32
    shapes = {name: np.shape(a) for name, a in channels.items()}
    first = next(iter(shapes.values()))
    if len(first) != 2 or any(s != first for s in shapes.values()):
        raise ValueError(f"write_exr: channels must be 2-D and of one size, got {shapes}")
    # OpenEXR writes non-contiguous arrays wrong without an error: always copy contiguous.
    data = {name: np.ascontiguousarray(a, dtype=dtype) for name, a in channels.items()}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp, OpenEXR.File(header, data) as exr:
        exr.write(str(tmp))
    return path
