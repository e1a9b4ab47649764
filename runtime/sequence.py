"""EXR frame sequences: find the frames, read them into canonical buffers, write outputs.

A sequence is given as
- a folder: its ``*.exr`` files except references (``ref_*``) and hidden files;
- a glob (quote it in the shell): ``'shots/a/frame_*.exr'`` (``ref_*`` files are skipped
  unless the pattern's file name itself starts with ``ref_``);
- a printf pattern: ``shots/a/frame_%04d.exr`` (exactly the names ``pattern % n``);
- a single EXR file (a one-frame sequence).
Frames are ordered by frame number, the last integer in the file stem; two files with
the same number are an error. References default to ``ref_NNNN.exr`` beside each frame
(same number); ``--reference`` may name a folder, glob or printf pattern instead.

Non-finite input values (NaN, Inf) are replaced by 0 and counted per frame (pixels with
any non-finite value in any buffer), so that nothing downstream sees them.

Per-sample input (the rank-5 `samples` buffer) is read when asked for: `sample_features`
names the features (runtime/samples.py: `sample<i>.*` layers, else S = 1 from the pixel
buffers).
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .exr import read_exr, read_exr_header, write_exr
from .layouts import Layout, extract_buffers, get_layout, resolve_channels
from .samples import read_samples, samples_from_buffers

Spec = str | os.PathLike
_LAST_INT = re.compile(r"(\d+)(?!.*\d)")
_PRINTF = re.compile(r"%(0?\d*)d")


@dataclass
class Frame:
    """One input frame: canonical buffers (C, H, W) float32 ((S, C, H, W) for `samples`),
    all finite."""

    index: int  # frame number from the file name (position in the sequence if it has none)
    path: Path
    buffers: dict[str, np.ndarray]
    nonfinite: int = 0  # pixels where some buffer had NaN/Inf (replaced by 0)
    nonfinite_buffers: tuple[str, ...] = field(default=())

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return tuple(self.buffers["color"].shape[1:])  # type: ignore[return-value]


def frame_number(path: Spec) -> int | None:
    """The last integer in the file stem (``frame_0012.exr`` -> 12), or None."""
    m = _LAST_INT.search(Path(path).stem)
    return int(m.group(1)) if m else None


def _is_glob(spec: str) -> bool:
    return any(c in spec for c in "*?[")


def _is_exr(p: Path) -> bool:
    return p.is_file() and p.suffix.lower() == ".exr" and not p.name.startswith(".")


def _printf_matches(spec: str) -> list[Path]:
    folder, name = os.path.split(spec)
    if "%" in folder or len(_PRINTF.findall(name)) != 1:
        raise InputError(f"{spec}: a printf pattern needs exactly one %d (e.g. frame_%04d.exr)")
    folder_path = Path(folder or ".")
    if not folder_path.is_dir():
        raise InputError(f"{spec}: folder {folder_path} does not exist")
    m = _PRINTF.search(name)
    regex = re.compile(re.escape(name[: m.start()]) + r"(\d+)" + re.escape(name[m.end() :]) + r"\Z")
    out = []
    for p in folder_path.iterdir():
        hit = regex.match(p.name)
        if hit and p.is_file() and p.name == name % int(hit.group(1)):
            out.append(p)
    return out


def _expand(spec: Spec, *, references: bool) -> list[Path]:
    """Files named by one spec (unsorted). `references`: list reference files of a folder."""
    text = os.fspath(spec)
    path = Path(text)
    if path.is_dir():
        files = [p for p in path.iterdir() if _is_exr(p)]
        refs = [p for p in files if p.name.startswith("ref_")]
        if references:
            return refs or files
        return [p for p in files if not p.name.startswith("ref_")]
    if path.is_file():
        return [path]
    if _PRINTF.search(path.name):
        return _printf_matches(text)
    if _is_glob(text):
        keep_refs = references or path.name.startswith("ref_")
        files = [Path(p) for p in glob.glob(text) if _is_exr(Path(p))]
        return [p for p in files if keep_refs or not p.name.startswith("ref_")]
    raise InputError(f"{text}: no such file or folder")


def _sorted_unique(files: list[Path], what: str) -> list[Path]:
    """Sort by frame number (files without one first, by name); refuse duplicate numbers."""
    seen: dict[int, Path] = {}
    ordered = sorted(
        set(files), key=lambda q: (frame_number(q) is not None, frame_number(q) or 0, str(q))
    )
    for p in ordered:
        n = frame_number(p)
        if n is not None and n in seen:
            raise InputError(f"two {what} with frame number {n}: {seen[n]} and {p}")
        if n is not None:
            seen[n] = p
    return ordered


def find_frames(spec: Spec | Sequence[Spec]) -> list[Path]:
    """EXR frames named by a folder, glob, printf pattern or file (or a list of these),
    sorted by frame number. InputError if none is found or two share a number."""
    specs = [spec] if isinstance(spec, str | os.PathLike) else list(spec)
    files: list[Path] = []
    for s in specs:
        found = _expand(s, references=False)
        if not found:
            raise InputError(f"{os.fspath(s)}: no EXR frames found")
        files.extend(found)
    return _sorted_unique(files, "frames")


def reference_index(spec: Spec) -> dict[int | None, Path]:
    """Frame number -> reference file for a reference folder, glob, printf pattern or file."""
    files = _expand(spec, references=True)
    if not files:
        raise InputError(f"{os.fspath(spec)}: no reference EXR files found")
    return {frame_number(p): p for p in _sorted_unique(files, "references")}


def find_reference(frame_path: Spec, reference_spec: Spec | None = None) -> Path | None:
    """The reference of a frame: ``ref_NNNN.exr`` beside it by default (same frame number),
    else the file with the frame's number in `reference_spec`; None if there is none."""
    frame_path = Path(frame_path)
    n = frame_number(frame_path)
    if reference_spec is not None:
        return reference_index(reference_spec).get(n)
    refs = [p for p in frame_path.parent.glob("ref_*") if _is_exr(p) and frame_number(p) == n]
    return _pick_reference(frame_path, refs)


def _pick_reference(frame_path: Path, candidates: list[Path]) -> Path | None:
    """`ref_<the frame's digits>.exr` if among the candidates (same number), else the only one."""
    m = _LAST_INT.search(frame_path.stem)
    if m:
        for c in candidates:
            if c.stem == f"ref_{m.group(1)}":
                return c
    return candidates[0] if len(candidates) == 1 else None


def match_references(
    frames: Sequence[Path], reference_spec: Spec | None = None
) -> list[Path | None]:
    """References for a whole sequence (indexes `reference_spec` once)."""
    if reference_spec is None:  # ref_NNNN.exr beside each frame: index each folder once
        folders: dict[Path, dict[int | None, list[Path]]] = {}
        for folder in {p.parent for p in frames}:
            refs = folders.setdefault(folder, {})
            for r in folder.glob("ref_*"):
                if _is_exr(r):
                    refs.setdefault(frame_number(r), []).append(r)
        return [_pick_reference(p, folders[p.parent].get(frame_number(p), [])) for p in frames]
    index = reference_index(reference_spec)
    if len(frames) == 1 and len(index) == 1:
        return [next(iter(index.values()))]
    return [index.get(frame_number(p)) for p in frames]


def _replace_nonfinite(buffers: dict[str, np.ndarray]) -> tuple[int, tuple[str, ...]]:
    bad_pixels: np.ndarray | None = None
    names = []
    for name, buf in buffers.items():
        bad = ~np.isfinite(buf)
        if bad.any():
            buf[bad] = 0.0
            names.append(name)
            px = bad.reshape(-1, *bad.shape[-2:]).any(axis=0)
            bad_pixels = px if bad_pixels is None else bad_pixels | px
    return (0 if bad_pixels is None else int(bad_pixels.sum())), tuple(names)


def _check_size(path: Path, size: tuple[int, int], expect: tuple[int, int] | None) -> None:
    if expect is not None and tuple(size) != tuple(expect):
        raise InputError(
            f"{path}: frame is {size[1]}x{size[0]} but the sequence is {expect[1]}x{expect[0]} "
            "(width x height); frames are not resized"
        )


def read_frame(
    path: Spec,
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    expect_size: tuple[int, int] | None = None,
    index: int | None = None,
    sample_features: Sequence[str] | None = None,
) -> Frame:
    """Read one frame into canonical buffers (layout conversion applied, NaN/Inf -> 0).

    `expect_size` = (height, width) the sequence has; a different size is an InputError.
    `sample_features`: also read the `samples` buffer with these per-sample features.
    """
    path = Path(path)
    layout = get_layout(layout) if isinstance(layout, str) else layout
    channels = read_exr(path)
    buffers = extract_buffers(channels, layout, overrides, source=str(path))
    size = buffers["color"].shape[1:]
    _check_size(path, size, expect_size)
    samples = (
        None if sample_features is None else read_samples(channels, sample_features, str(path))
    )
    if samples is not None:
        buffers["samples"] = samples
    nonfinite, bad = _replace_nonfinite(buffers)
    buffers = layout.convert(buffers)
    if sample_features is not None and samples is None:  # S = 1 from the pixel buffers
        buffers["samples"] = samples_from_buffers(buffers, sample_features)
    n = frame_number(path)
    return Frame(
        index=n if n is not None else (index or 0),
        path=path,
        buffers=buffers,
        nonfinite=nonfinite,
        nonfinite_buffers=bad,
    )


def read_reference(
    path: Spec,
    layout: Layout | str = "canonical",
    expect_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """A reference image (3, H, W) float32: channels R,G,B, else the layout's `color` source.
    NaN/Inf are replaced by 0."""
    path = Path(path)
    channels = read_exr(path)
    if not all(c in channels for c in "RGB"):
        layout = get_layout(layout) if isinstance(layout, str) else layout
        only_color = {b: "none" for b in ("color_b", "albedo", "normal", "depth", "motion")}
        names = resolve_channels(channels, layout, only_color, source=str(path))["color"]
        channels = {c: channels[n] for c, n in zip("RGB", names, strict=True)}
    rgb = np.stack([channels[c] for c in "RGB"]).astype(np.float32, copy=False)
    _check_size(path, rgb.shape[1:], expect_size)
    return np.nan_to_num(rgb, nan=0.0, posinf=0.0, neginf=0.0)


def scan_reference(
    path: Spec, layout: Layout | str = "canonical", expect_size: tuple[int, int] | None = None
) -> None:
    """Header-only check of a reference: R,G,B (or the layout's colour) present, right size."""
    path = Path(path)
    sizes = read_exr_header(path)
    names = list("RGB")
    if not all(c in sizes for c in names):
        layout = get_layout(layout) if isinstance(layout, str) else layout
        only_color = {b: "none" for b in ("color_b", "albedo", "normal", "depth", "motion")}
        names = resolve_channels(sizes, layout, only_color, source=str(path))["color"]
    _check_size(path, sizes[names[0]], expect_size)


def scan_sequence(
    paths: Sequence[Path],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
) -> tuple[int, int]:
    """Check every frame's header (channels present, one size) before reading pixels.

    Returns the sequence's (height, width). Raises InputError naming the first bad file.
    """
    layout = get_layout(layout) if isinstance(layout, str) else layout
    size: tuple[int, int] | None = None
    first: Path | None = None
    for p in paths:
        sizes = read_exr_header(p)
        mapping = resolve_channels(sizes, layout, overrides, source=str(p))
        used = {sizes[n] for names in mapping.values() for n in names}
        if len(used) > 1:
            raise InputError(f"{p}: the selected channels differ in size: {sorted(used)}")
        (this,) = used
        if size is None:
            size, first = this, p
        elif this != size:
            raise InputError(
                f"{p}: frame is {this[1]}x{this[0]} but {first} is {size[1]}x{size[0]} "
                "(width x height); frames are not resized"
            )
    if size is None:
        raise InputError("empty sequence")
    return size


def iter_sequence(
    spec: Spec | Sequence[Spec],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    sample_features: Sequence[str] | None = None,
) -> Iterator[Frame]:
    """Frames of a sequence in order, after checking all headers (channels, one size)."""
    paths = find_frames(spec)
    size = scan_sequence(paths, layout, overrides)
    for i, p in enumerate(paths):
        yield read_frame(p, layout, overrides, size, i, sample_features)


HALF_MAX = 65504.0


def as_written(rgb: np.ndarray, half: bool = True) -> np.ndarray:
    """The values `write_output` stores: float32, or half precision clamped to +-65504
    (larger HDR values would become Inf in a half-float file)."""
    rgb = np.asarray(rgb, dtype=np.float32)
    if not half:
        return rgb
    return np.clip(rgb, -HALF_MAX, HALF_MAX).astype(np.float16).astype(np.float32)


def write_output(path: Spec, rgb: np.ndarray, half: bool = True) -> Path:
    """Write a (3, H, W) image as channels R,G,B (half float by default, clamped to the half
    range, ZIP compression), atomically."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 4 and rgb.shape[0] == 1:
        rgb = rgb[0]
    if rgb.ndim != 3 or rgb.shape[0] != 3:
        raise ValueError(f"write_output: expected a (3, H, W) image, got {rgb.shape}")
    rgb = as_written(rgb, half)
    return write_exr(path, {"R": rgb[0], "G": rgb[1], "B": rgb[2]}, half=half)
