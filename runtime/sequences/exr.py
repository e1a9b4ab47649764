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

Before any pixel is decoded the header is checked (`check_header`): a part larger than the
pixel limit (`max_pixels`, default `DEFAULT_MAX_PIXELS`, or `pixel_limit(n)` around the
calls) is refused, since a few MB of compressed file can decode to gigabytes; so are deep
parts and tiled multi-level (mip/rip-map) parts, which the bindings cannot read as flat
images.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np
import OpenEXR

from ..errors import InputError
from .atomic import atomic_path

# 8192 x 8192: one such frame with its five guide buffers decodes to some 4 GiB of float32
# (plus the file's own decode): the most a 24 GiB machine running several jobs should take.
DEFAULT_MAX_PIXELS = 8192 * 8192
_MAX_PIXELS: ContextVar[int] = ContextVar("rtdenoise_exr_max_pixels", default=DEFAULT_MAX_PIXELS)


@contextmanager
def pixel_limit(max_pixels: int | None) -> Iterator[None]:
    """Within the block, EXR reads refuse parts of more than `max_pixels` pixels (None: the
    default); per thread / async context."""
    if max_pixels is not None and max_pixels < 1:
        raise InputError(f"the pixel limit must be >= 1, got {max_pixels}")
    token = _MAX_PIXELS.set(DEFAULT_MAX_PIXELS if max_pixels is None else int(max_pixels))
    try:
        yield
    finally:
        _MAX_PIXELS.reset(token)


def current_pixel_limit() -> int:
    """The pixel limit reads use now (`pixel_limit`, else `DEFAULT_MAX_PIXELS`)."""
    return _MAX_PIXELS.get()


Window = tuple[tuple[int, int], tuple[int, int]]  # ((x min, y min), (x max, y max)), inclusive


def _window(value: object) -> Window:
    (x0, y0), (x1, y1) = (tuple(int(v) for v in c) for c in value)  # type: ignore[attr-defined]
    return (x0, y0), (x1, y1)


def _check_part(path: Path, i: int, header: dict, max_pixels: int) -> tuple[int, int]:
    """(height, width) of one part's data window after checking that it can be read flat
    and within the pixel limit; InputError naming the file and what is unsupported."""
    where = f"part {i}" + (f" ({header['name']!r})" if header.get("name") else "")
    storage = str(header.get("type", "")).rsplit(".", 1)[-1]
    if "deep" in storage:
        raise InputError(
            f"{path}: {where} is a deep EXR ({storage}: several samples per pixel); "
            "flatten it to a scanline or tiled image first"
        )
    tiles = header.get("tiles")
    mode = getattr(tiles, "mode", None)
    if tiles is not None and mode is not None and mode != OpenEXR.ONE_LEVEL:
        raise InputError(
            f"{path}: {where} is a tiled multi-level EXR ({str(mode).rsplit('.', 1)[-1]}); "
            "the reader takes single-level images only: write it with one level"
        )
    (x0, y0), (x1, y1) = _window(header["dataWindow"])
    h, w = y1 - y0 + 1, x1 - x0 + 1
    if h < 1 or w < 1:
        raise InputError(f"{path}: {where} has an empty data window {((x0, y0), (x1, y1))}")
    if h * w > max_pixels:
        raise InputError(
            f"{path}: {where} is {w}x{h} ({h * w} pixels), above the pixel limit of "
            f"{max_pixels} (denoise-run --max-pixels, or read_exr(max_pixels=...))"
        )
    return h, w


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


def _decode(path: Path, sizes: dict[str, tuple[int, int]]) -> dict[str, np.ndarray]:
    """Every channel the bindings decode, as 2-D arrays in the file's own pixel type (sizes:
    the header's, for the out-of-memory message)."""
    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            parts = [(_part_name(p), list(p.channels)) for p in exr.parts]
            names = qualified_names(path, parts)
            channels: dict[str, np.ndarray] = {}
            for part, mapping in zip(exr.parts, names, strict=True):
                for name, channel in part.channels.items():
                    pixels = np.asarray(channel.pixels)
                    if pixels.ndim != 2 or pixels.dtype == object:
                        raise InputError(
                            f"{path}: channel {name!r} decodes to {pixels.dtype} {pixels.shape}, "
                            "expected a 2-D image (a deep or multi-level part?)"
                        )
                    channels[mapping[name]] = pixels
    except InputError:
        raise
    except MemoryError:
        (h, w) = max(sizes.values(), key=lambda s: s[0] * s[1])
        raise InputError(
            f"{path}: out of memory decoding its {w}x{h} frame ({len(sizes)} channels); "
            "lower --max-pixels or free memory"
        ) from None
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
    max_pixels: int | None = None,
) -> dict[str, np.ndarray]:
    """Channels of an EXR file (every part) as contiguous 2-D arrays.

    channels: only these (InputError naming the file and the first absent channel); None: all.
    dtype: convert to this type (default float32); None keeps the file's type (float16 for
        half channels) without a copy, for callers that convert while stacking.
    max_pixels: refuse parts above this many pixels from the header, before any decode
        (None: `current_pixel_limit()`); deep and tiled multi-level parts are refused too.
    """
    path = Path(path)
    listed = read_exr_header(path, max_pixels=max_pixels)  # size, deep, levels: before decode
    decoded = _decode(path, listed)
    if channels is None:
        # OpenEXR 3.5 drops the parts whose pixels it cannot read (truncated file) with only
        # a printed warning: compare with the channels the headers list.
        lost = sorted(set(listed) - set(decoded))
        if lost:
            raise _lost_error(path, lost)
        if not decoded:
            raise InputError(f"{path}: EXR file has no channels")
        names: Collection[str] = decoded
    else:
        absent = [n for n in channels if n not in decoded]
        if absent:  # the header tells a dropped (truncated) part from a channel never there
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


def read_exr_header(
    path: str | os.PathLike, *, max_pixels: int | None = None
) -> dict[str, tuple[int, int]]:
    """Channel name -> (height, width) of every part, reading headers only (no pixels).

    InputError for a part above `max_pixels` (None: `current_pixel_limit()`), a deep part or
    a tiled multi-level part: `read_exr` would refuse them before decoding.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    limit = current_pixel_limit() if max_pixels is None else max_pixels
    try:
        with OpenEXR.File(str(path), separate_channels=True, header_only=True) as exr:
            parts = [(_part_name(p), [c.name for c in p.header["channels"]]) for p in exr.parts]
            names = qualified_names(path, parts)
            sizes: dict[str, tuple[int, int]] = {}
            for i, (part, mapping) in enumerate(zip(exr.parts, names, strict=True)):
                size = _check_part(path, i, part.header, limit)
                for channel in part.header["channels"]:
                    sizes[mapping[channel.name]] = size
    except InputError:
        raise
    except Exception as exc:  # OpenEXR raises RuntimeError for truncated/corrupt headers
        raise InputError(f"{path}: cannot read EXR ({exc})") from exc
    if not sizes:
        raise InputError(f"{path}: EXR file has no channels")
    return sizes


def read_exr_windows(path: str | os.PathLike) -> tuple[Window, Window]:
    """(data window, display window) of the file's first part, from its header; each
    ((x min, y min), (x max, y max)), inclusive."""
    path = Path(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:
            header = exr.parts[0].header
            return _window(header["dataWindow"]), _window(header["displayWindow"])
    except Exception as exc:
        raise InputError(f"{path}: cannot read EXR ({exc})") from exc


def read_exr_attributes(path: str | os.PathLike, prefix: str = "") -> dict[str, str]:
    """The string attributes of the file's first part whose names start with `prefix`, from
    its header (no pixels); InputError naming the file when it does not read."""
    path = Path(path)
    try:
        with OpenEXR.File(str(path), header_only=True) as exr:  # the header lives with it
            header = exr.parts[0].header
            return {k: v for k, v in header.items() if k.startswith(prefix) and isinstance(v, str)}
    except Exception as exc:  # OpenEXR raises RuntimeError for truncated/corrupt headers
        raise InputError(f"{path}: cannot read the EXR header ({exc})") from None


def write_exr(
    path: str | os.PathLike,
    channels: dict[str, np.ndarray],
    *,
    half: bool = True,
    windows: tuple[Window, Window] | None = None,
    attributes: Mapping[str, str] | None = None,
) -> Path:
    """Write 2-D channels to a single-part, ZIP-compressed EXR, atomically.

    `half=True` stores float16 (the default for denoised output), else float32. Arrays
    already of that type and contiguous are written as they are (no conversion, no copy).
    windows: (data window, display window) to store, e.g. the input's (`read_exr_windows`);
    the data window must match the channels' size. None: both (0, 0) to the size.
    attributes: string attributes for the header (e.g. `provenance.record`'s), read back by
    `read_exr_attributes`.
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
    if windows is not None:
        data_window, display_window = windows
        (x0, y0), (x1, y1) = data_window
        if (y1 - y0 + 1, x1 - x0 + 1) != tuple(first):
            raise ValueError(
                f"write_exr: data window {data_window} is {x1 - x0 + 1}x{y1 - y0 + 1}, the "
                f"channels are {first[1]}x{first[0]}"
            )
        header["dataWindow"], header["displayWindow"] = data_window, display_window
    for key, value in (attributes or {}).items():
        if key in header or not isinstance(value, str):
            raise ValueError(f"write_exr: attribute {key!r} must be a new name with a str value")
        header[key] = value
    with atomic_path(path) as tmp, OpenEXR.File(header, data) as exr:
        exr.write(str(tmp))
    return path
