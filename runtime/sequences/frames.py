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

Channels are resolved once per sequence: `plan_sequence` reads every header, maps the
layout's layers to channel names from the first frame, checks that every frame has those
channels at one size, and its `SequencePlan.read` then reads only the planned channels
(converting only those to float32). `read_frame` is the one-file form of the same reader.

Non-finite input values (NaN, Inf) are replaced (by 0, or as runtime/guard.py says for depth
and motion) and counted per frame (pixels with any non-finite value in any buffer), so that
nothing downstream sees them; `Denoiser.process` guards the buffers again (ranges, outliers).

Per-sample input: asking for the rank-5 `samples` buffer (among `buffers`) reads the
`sample<i>.*` layers of the per-sample features `sample_features` (runtime/sequences/samples.py; the
default set when not given), or makes S = 1 from the pixel buffers when a file has none.
"""

from __future__ import annotations

import glob
import json
import os
import re
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..contract import BUFFER_CHANNELS, HALF_MAX, SAMPLES
from ..errors import InputError
from ..guard import replace_nonfinite
from .exr import Window, read_exr, read_exr_header, write_exr
from .layouts import Layout, check_channels, get_layout, resolve_channels, stack_buffers
from .samples import DEFAULT_SAMPLE_FEATURES, SamplePlan, plan_samples, samples_from_buffers

Spec = str | os.PathLike
_LAST_INT = re.compile(r"(\d+)(?!.*\d)")
_PRINTF = re.compile(r"%(0?\d*)d")


@dataclass
class Frame:
    """One input frame: canonical buffers (C, H, W) float32, all finite."""

    index: int  # frame number from the file name (position in the sequence if it has none)
    path: Path
    buffers: dict[str, np.ndarray]
    nonfinite: int = 0  # pixels where some buffer had NaN/Inf (replaced by 0)
    nonfinite_buffers: tuple[str, ...] = field(default=())

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return tuple(self.buffers["color"].shape[1:])  # type: ignore[return-value]


def shot_cuts(folder: str | os.PathLike) -> tuple[int, ...]:
    """The frame numbers that start a new shot inside a rendered sequence: `cuts` of the
    meta.json beside its frames (denoise-render writes it, docs/data.md); none without one.
    A host resets the history there (a camera cut). InputError for an unreadable list."""
    path = Path(folder) / "meta.json"
    if not path.is_file():
        return ()
    try:
        cuts = json.loads(path.read_text()).get("cuts", [])
        return tuple(sorted(int(c) for c in cuts))
    except (ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"{path}: unreadable 'cuts' ({exc})") from exc


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


def group_shots(specs: Sequence[Spec]) -> list[tuple[str, list[Spec]]]:
    """Several inputs -> shots, (name, specs) each, in the order given.

    Each folder, glob or printf pattern is one shot; EXR files given one by one (e.g. an
    unquoted glob the shell expanded) are one shot per folder. A shot is named after its
    folder, with as many parent folders as it takes to tell it from the others (``a/render``
    and ``b/render``, but ``c``); InputError for two shots in one folder (two patterns).
    """
    groups: dict[tuple[str, Path], list[Spec]] = {}
    for spec in specs:
        path = Path(os.fspath(spec))
        if path.is_dir():
            key = ("folder", path.resolve())
        elif path.is_file():
            key = ("folder", path.parent.resolve())
        else:  # a glob or printf pattern: a shot of its own
            key = (os.fspath(spec), path.parent.resolve())
        groups.setdefault(key, []).append(spec)
    folders = [folder.parts for _, folder in groups]
    seen: dict[tuple[str, ...], Spec] = {}
    for parts, shot in zip(folders, groups.values(), strict=True):
        if parts in seen:
            raise InputError(
                f"{os.fspath(seen[parts])} and {os.fspath(shot[0])} are two shots in one folder; "
                "give each shot its own folder, or run them one at a time"
            )
        seen[parts] = shot[0]
    names = []
    for parts in folders:  # the shortest trailing part of its path that no other shot shares
        k = 1
        while k < len(parts) and any(q[-k:] == parts[-k:] for q in folders if q != parts):
            k += 1
        names.append("/".join(parts[-k:]))
    return list(zip(names, groups.values(), strict=True))


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
    """NaN/Inf replaced in place by each buffer's rule (runtime/guard.py: 0 mostly, the far
    plane for +Inf depth, off-screen for motion); (pixels with any in any buffer, names)."""
    bad_pixels: np.ndarray | None = None
    names = []
    for name, buf in buffers.items():
        px = replace_nonfinite(name, buf)
        if px is not None:
            names.append(name)
            bad_pixels = px if bad_pixels is None else bad_pixels | px
    return (0 if bad_pixels is None else int(bad_pixels.sum())), tuple(names)


def _check_size(path: Path, size: tuple[int, int], expect: tuple[int, int] | None) -> None:
    if expect is not None and tuple(size) != tuple(expect):
        raise InputError(
            f"{path}: frame is {size[1]}x{size[0]} but the sequence is {expect[1]}x{expect[0]} "
            "(width x height); frames are not resized"
        )


def _layout(layout: Layout | str) -> Layout:
    return get_layout(layout) if isinstance(layout, str) else layout


def _read_mapped(
    path: Path,
    layout: Layout,
    channels: Mapping[str, Sequence[str]],
    expect_size: tuple[int, int] | None,
    index: int | None,
    samples: SamplePlan | None = None,
) -> Frame:
    """Read the mapped channels only, stack them into float32 buffers, NaN/Inf -> 0 (one
    pass per buffer), then the layout's conversion (and the samples buffer, if planned)."""
    names = [n for ns in channels.values() for n in ns]
    raw = read_exr(path, names + (samples.channel_names if samples else []), dtype=None)
    buffers = stack_buffers(raw, channels, source=str(path))
    _check_size(path, buffers["color"].shape[1:], expect_size)
    if samples is not None and samples.layers:
        buffers[SAMPLES] = samples.stack(raw)
    nonfinite, bad = _replace_nonfinite(buffers)
    buffers = layout.convert(buffers)
    if samples is not None and not samples.layers:  # S = 1 from the pixel buffers
        buffers[SAMPLES] = samples_from_buffers(buffers, samples.features)
    n = frame_number(path)
    return Frame(
        index=n if n is not None else (index or 0),
        path=path,
        buffers=buffers,
        nonfinite=nonfinite,
        nonfinite_buffers=bad,
    )


def read_frame(
    path: Spec,
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    expect_size: tuple[int, int] | None = None,
    index: int | None = None,
    *,
    buffers: Collection[str] | None = None,
    sample_features: Sequence[str] | None = None,
) -> Frame:
    """Read one frame into canonical buffers (layout conversion applied, NaN/Inf -> 0).

    `expect_size` = (height, width) the sequence has; a different size is an InputError.
    buffers: read only these (and `color`) when the file has them; None: every buffer found.
    `samples` among them (or `sample_features` given) also reads the per-sample buffer.
    Resolves the channels from this file's header; for a sequence, `plan_sequence` resolves
    them once.
    """
    path = Path(path)
    layout = _layout(layout)
    header = read_exr_header(path)
    samples = _plan_samples(header, buffers, sample_features, str(path))
    pixel = _pixel_buffers(buffers, samples)
    mapping = resolve_channels(header, layout, overrides, source=str(path), buffers=pixel)
    if pixel is not None:
        mapping = {b: names for b, names in mapping.items() if b in pixel or b == "color"}
    return _read_mapped(path, layout, mapping, expect_size, index, samples)


def _plan_samples(
    header: Collection[str],
    buffers: Collection[str] | None,
    features: Sequence[str] | None,
    source: str,
) -> SamplePlan | None:
    """The samples plan when `samples` is asked for (in `buffers` or by naming features)."""
    if features is None and (buffers is None or SAMPLES not in buffers):
        return None
    return plan_samples(header, features or DEFAULT_SAMPLE_FEATURES, source)


def _pixel_buffers(
    buffers: Collection[str] | None, samples: SamplePlan | None
) -> tuple[str, ...] | None:
    """The canonical buffers to read: `buffers` without `samples`, plus those S = 1 is made of."""
    if buffers is None:
        return None
    pixel = [b for b in buffers if b != SAMPLES]
    return tuple(dict.fromkeys((*pixel, *(samples.pixel_buffers() if samples else ()))))


@dataclass(frozen=True)
class SequencePlan:
    """How every frame of a sequence is read: channels resolved once, from the headers."""

    layout: Layout
    channels: Mapping[str, tuple[str, ...]]  # buffer -> EXR channel names, the buffers read
    size: tuple[int, int]  # (height, width) of every frame
    samples: SamplePlan | None = None  # the per-sample buffer, when asked for

    def read(self, path: Spec, index: int | None = None) -> Frame:
        """Read one frame of the sequence: only the planned channels, NaN/Inf -> 0."""
        return _read_mapped(Path(path), self.layout, self.channels, self.size, index, self.samples)


def _needed_mapping(
    names: Collection[str],
    layout: Layout,
    overrides: Mapping[str, str],
    buffers: Collection[str] | None,
    source: str,
) -> dict[str, list[str]]:
    """resolve_channels for the buffers a model needs: each must be found."""
    if buffers is None:
        return resolve_channels(names, layout, overrides, source)
    needed = list(dict.fromkeys(("color", *buffers)))
    for b in needed:
        value = overrides.get(b)
        if value is not None and value.lower() == "none":
            raise InputError(
                f"{source}: the model needs buffer {b!r}, which --channel {b}=none leaves out"
            )
        if value is None and not layout.layers.get(b):
            raise InputError(
                f"{source}: the model needs buffer {b!r}, for which layout {layout.name} has "
                f"no layer (use --channel {b}=LAYER)"
            )
    return resolve_channels(names, layout, overrides, source, buffers=needed, required=needed)


def plan_sequence(
    paths: Sequence[Path],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    *,
    buffers: Collection[str] | None = None,
    sample_features: Sequence[str] | None = None,
) -> SequencePlan:
    """Check every frame's header and resolve the channels once, before reading pixels.

    buffers: the buffers to read (a model's `required_buffers`; `color` always), each of
        which must be found; other layers are neither checked nor read, except buffers named
        in `overrides`, whose channels must exist. None: every buffer the first frame has.
        `samples` among them reads the per-sample buffer (features `sample_features`, else
        the default set): the first frame's sample layers in every frame, or S = 1 from the
        pixel buffers when it has none.
    The mapping comes from the first frame; every frame must hold its channels at one size.
    Raises InputError naming the first bad file (and channel).
    """
    layout = _layout(layout)
    overrides = dict(overrides or {})
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("empty sequence")
    first = paths[0]
    sizes = read_exr_header(first)
    samples = _plan_samples(sizes, buffers, sample_features, str(first))
    buffers = _pixel_buffers(buffers, samples)
    mapping = _needed_mapping(sizes, layout, overrides, buffers, str(first))
    if samples is not None and samples.layers:
        mapping = {**mapping, SAMPLES: samples.channel_names}  # checked like the buffers
    size: tuple[int, int] | None = None
    for p in paths:
        if p != first:
            sizes = read_exr_header(p)
            check_channels(sizes, mapping, layout, source=str(p))
        names = [n for ns in mapping.values() for n in ns]
        this = sizes[names[0]]
        odd = next((n for n in names if sizes[n] != this), None)
        if odd is not None:
            (h, w), (h0, w0) = sizes[odd], this
            raise InputError(
                f"{p}: channel {odd!r} is {w}x{h} but channel {names[0]!r} is {w0}x{h0}"
            )
        if size is None:
            size = this
        elif this != size:
            raise InputError(
                f"{p}: frame is {this[1]}x{this[0]} but {first} is {size[1]}x{size[0]} "
                "(width x height); frames are not resized"
            )
    assert size is not None
    read = {
        b: tuple(ns)
        for b, ns in mapping.items()
        if b != SAMPLES and (buffers is None or b in buffers or b == "color")
    }
    return SequencePlan(layout=layout, channels=read, size=size, samples=samples)


def _reference_channels(names: Collection[str], layout: Layout | str, path: Path) -> list[str]:
    """R,G,B of a reference, else the channels of the layout's `color`."""
    if all(c in names for c in "RGB"):
        return list("RGB")
    only_color = {b: "none" for b in BUFFER_CHANNELS if b != "color"}
    return resolve_channels(names, _layout(layout), only_color, source=str(path))["color"]


def reference_pixels(
    path: Spec,
    layout: Layout | str = "canonical",
    expect_size: tuple[int, int] | None = None,
) -> tuple[np.ndarray, int]:
    """A reference image (3, H, W) float32 (channels R,G,B, else the layout's `color` source)
    and how many of its pixels had NaN/Inf (replaced by 0: such a reference cannot score)."""
    path = Path(path)
    names = _reference_channels(read_exr_header(path), layout, path)
    rgb = stack_buffers(read_exr(path, names, dtype=None), {"color": names}, str(path))["color"]
    _check_size(path, rgb.shape[1:], expect_size)
    bad = replace_nonfinite("color", rgb)
    return rgb, 0 if bad is None else int(bad.sum())


def read_reference(
    path: Spec,
    layout: Layout | str = "canonical",
    expect_size: tuple[int, int] | None = None,
) -> np.ndarray:
    """A reference image (3, H, W) float32: channels R,G,B, else the layout's `color` source.
    NaN/Inf are replaced by 0 (`reference_pixels` counts them). Reads only those channels."""
    return reference_pixels(path, layout, expect_size)[0]


def scan_reference(
    path: Spec, layout: Layout | str = "canonical", expect_size: tuple[int, int] | None = None
) -> None:
    """Header-only check of a reference: R,G,B (or the layout's colour) present, right size."""
    path = Path(path)
    sizes = read_exr_header(path)
    names = _reference_channels(sizes, layout, path)
    _check_size(path, sizes[names[0]], expect_size)


def scan_sequence(
    paths: Sequence[Path],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
) -> tuple[int, int]:
    """Check every frame's header (channels present, one size) before reading pixels.

    Returns the sequence's (height, width). Raises InputError naming the first bad file.
    """
    return plan_sequence(paths, layout, overrides).size


def iter_sequence(
    spec: Spec | Sequence[Spec],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    *,
    buffers: Collection[str] | None = None,
    sample_features: Sequence[str] | None = None,
) -> Iterator[Frame]:
    """Frames of a sequence in order, after checking all headers (channels, one size).

    spec: a folder, glob, printf pattern or file (or a list). layout: a preset name, a layout
    file (.toml) or a Layout. buffers: read only these (e.g. `Denoiser.required_buffers`),
    each of which every frame must have; None: every buffer the layout finds. A per-sample
    model's `samples` is read with `sample_features` (`sample_features_of(denoiser.config)`).
    """
    paths = find_frames(spec)
    plan = plan_sequence(paths, layout, overrides, buffers=buffers, sample_features=sample_features)
    for i, p in enumerate(paths):
        yield plan.read(p, index=i)


def quantize_output(rgb: np.ndarray, half: bool = True) -> np.ndarray:
    """The C-contiguous array `write_output` stores: float16 clamped to +-65504 (larger HDR
    values would become Inf in a half-float file), or float32."""
    rgb = np.asarray(rgb, dtype=np.float32)
    if not half:
        return np.ascontiguousarray(rgb)
    return np.clip(rgb, -HALF_MAX, HALF_MAX).astype(np.float16)


def as_written(rgb: np.ndarray, half: bool = True) -> np.ndarray:
    """The values `write_output` stores, as float32."""
    return quantize_output(rgb, half).astype(np.float32, copy=False)


def write_rgb(
    path: Spec,
    data: np.ndarray,
    half: bool = True,
    windows: tuple[Window, Window] | None = None,
    attributes: Mapping[str, str] | None = None,
) -> Path:
    """Write a (3, H, W) array from `quantize_output` as channels R,G,B (ZIP), atomically,
    without converting it again; `windows`: the (data, display) windows to keep;
    `attributes`: string header attributes (what made the output: sequences/provenance.py)."""
    rgb = {"R": data[0], "G": data[1], "B": data[2]}
    return write_exr(path, rgb, half=half, windows=windows, attributes=attributes)


def write_output(path: Spec, rgb: np.ndarray, half: bool = True) -> Path:
    """Write a (3, H, W) image as channels R,G,B (half float by default, clamped to the half
    range, ZIP compression), atomically."""
    rgb = np.asarray(rgb)
    if rgb.ndim == 4 and rgb.shape[0] == 1:
        rgb = rgb[0]
    if rgb.ndim != 3 or rgb.shape[0] != 3:
        raise ValueError(f"write_output: expected a (3, H, W) image, got {rgb.shape}")
    return write_rgb(path, quantize_output(rgb, half), half)
