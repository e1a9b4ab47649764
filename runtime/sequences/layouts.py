"""Channel layouts: which EXR channels hold which canonical buffer, and their conventions.

A *layout* names, for every canonical buffer (docs/contract.md), the EXR layers it
may come from, tried in order, and a conversion to the canonical conventions
applied after reading. Layouts are data: TOML files (docs/layouts.md). Two presets ship in
`rtdenoise/assets/layouts/`:

- ``canonical`` (docs/contract.md, "Buffers"): ``R,G,B`` (noisy colour), ``colorB.R/G/B``,
  ``albedo.R/G/B``, ``normal.X/Y/Z``, ``depth.Z``, ``motion.X/Y``; no conversion.
- ``blender`` (Cycles multilayer, any view-layer prefix): ``Noisy Image`` (else
  ``Combined``), ``Denoising Albedo`` (clamped to [0, 1]), ``Denoising Normal``
  (camera space, kept as is), ``Denoising Depth.Z``, ``Vector.X/Y`` converted to
  our motion convention: previous = current + (Vector.X, -Vector.Y).

`get_layout` takes a preset name or the path of a user's ``.toml`` file (a copy of a preset,
edited for a renderer).

Channel matching (one rule for layouts and ``--channel`` overrides). A buffer
with C channels read from layer ``L`` uses the channels ``L.<c>`` for the first
component set that is complete: C = 3: ``R,G,B`` then ``X,Y,Z``; C = 2: ``X,Y``,
``R,G``, ``U,V``; C = 1: the channel ``L`` itself, then ``L.Z``, ``L.R``,
``L.Y``, ``L.V``. The empty layer ``""`` means bare names (``R``, ``G``, ``B``).
A name matches exactly or, failing that, with any one prefix
(``ViewLayer.L.<c>``); two prefixes holding the same layer is an error (name the
layer with its prefix to choose). A layer with only some of its channels is an
error naming the missing ones. A source may instead list exactly C full channel
names, comma-separated (``mv.U,mv.V``): a layout file's ``channels`` key, or an override.

Overrides (``--channel BUFFER=VALUE``): VALUE is a layer name as above, a
comma-separated list of exactly C full channel names (``motion=mv.U,mv.V``), or
``none`` to ignore the buffer. An overridden buffer is required; the layout's
conversion still applies (the layout states the file's conventions).
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rtdenoise.shipped import LAYOUTS_DIR

from ..contract import BUFFER_CHANNELS
from ..errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

COMPONENT_SETS: dict[int, tuple[tuple[str, ...], ...]] = {
    3: (("R", "G", "B"), ("X", "Y", "Z")),
    2: (("X", "Y"), ("R", "G"), ("U", "V")),
    1: (("Z",), ("R",), ("Y",), ("V",)),
}
MOTION_UNITS = ("pixels", "uv")  # uv: a fraction of the image, x times width, y times height
BUFFER_KEYS = ("layers", "channels", "scale", "offset", "clamp", "units")
LAYOUT_KEYS = ("description", "required", "buffers")

Buffers = dict[str, np.ndarray]


@dataclass(frozen=True)
class Transform:
    """How one buffer's file values become canonical: ``clamp((v * scale + offset) * size)``,
    per channel; `size` = (width, height) for motion in ``uv`` units, else 1."""

    scale: tuple[float, ...] | None = None
    offset: tuple[float, ...] | None = None
    clamp: tuple[float, float] | None = None
    units: str = "pixels"

    def apply(self, a: np.ndarray) -> np.ndarray:
        """Convert a (C, H, W) float32 buffer in place; returns it."""
        shape = (-1,) + (1,) * (a.ndim - 1)
        if self.scale is not None:
            a *= np.asarray(self.scale, np.float32).reshape(shape)
        if self.offset is not None:
            a += np.asarray(self.offset, np.float32).reshape(shape)
        if self.units == "uv":
            h, w = a.shape[-2:]
            a *= np.asarray((w, h), np.float32).reshape(shape)
        if self.clamp is not None:
            np.clip(a, self.clamp[0], self.clamp[1], out=a)
        return a


@dataclass(frozen=True)
class Layout:
    """Where each canonical buffer lives in a file and how to convert it."""

    name: str
    description: str
    layers: Mapping[str, tuple[str, ...]]  # buffer -> candidate sources, tried in order
    transforms: Mapping[str, Transform] = field(default_factory=dict)
    required: tuple[str, ...] = ("color",)
    path: Path | None = None  # the TOML file it was read from

    def convert(self, buffers: Buffers) -> Buffers:
        """File conventions -> canonical ones, in place on the buffers' own arrays."""
        for name, transform in self.transforms.items():
            if name in buffers:
                buffers[name] = transform.apply(buffers[name])
        return buffers


def _floats(value: Any, n: int, where: str) -> tuple[float, ...]:
    """A number (for every channel) or a list of `n` numbers."""
    items = value if isinstance(value, list) else [value] * n
    if len(items) != n or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in items
    ):
        raise InputError(f"{where}: expected a number or a list of {n} numbers, got {value!r}")
    return tuple(float(v) for v in items)


def _strings(value: Any, where: str) -> list[str]:
    items = [value] if isinstance(value, str) else value
    if not isinstance(items, list) or not all(isinstance(v, str) for v in items):
        raise InputError(f"{where}: expected a string or a list of strings, got {value!r}")
    return items


def _unknown(keys: Iterable[str], allowed: Sequence[str], where: str) -> None:
    extra = sorted(set(keys) - set(allowed))
    if extra:
        raise InputError(f"{where}: unknown key {extra[0]!r}; keys: {', '.join(allowed)}")


def _buffer_entry(buf: str, entry: Any, where: str) -> tuple[tuple[str, ...], Transform | None]:
    """(candidate sources, transform) of one `[buffers.<buf>]` table."""
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected a table ([buffers.{buf}])")
    _unknown(entry, BUFFER_KEYS, where)
    n = BUFFER_CHANNELS[buf]
    sources: list[str] = []
    if "channels" in entry:
        names = _strings(entry["channels"], f"{where}.channels")
        if len(names) != n or not all(names) or any("," in c for c in names):
            raise InputError(f"{where}.channels: {buf} needs {n} channel names, got {names!r}")
        sources.append(",".join(names))
    sources += _strings(entry.get("layers", []), f"{where}.layers")
    if not sources:
        raise InputError(f"{where}: give `layers` (layer names) or `channels` (exact names)")
    units = entry.get("units", "pixels")
    if units not in MOTION_UNITS or (units != "pixels" and buf != "motion"):
        raise InputError(
            f"{where}.units: {units!r}; units apply to motion only: {', '.join(MOTION_UNITS)}"
        )
    clamp = None
    if "clamp" in entry:
        clamp = _floats(entry["clamp"], 2, f"{where}.clamp")
        if not clamp[0] <= clamp[1]:
            raise InputError(f"{where}.clamp: expected [low, high] with low <= high")
    transform = Transform(
        scale=_floats(entry["scale"], n, f"{where}.scale") if "scale" in entry else None,
        offset=_floats(entry["offset"], n, f"{where}.offset") if "offset" in entry else None,
        clamp=clamp,
        units=units,
    )
    return tuple(sources), None if transform == Transform() else transform


def parse_layout(data: Mapping[str, Any], name: str, source: str = "<layout>") -> Layout:
    """A Layout from the parsed TOML of a layout file; InputError naming `source` and the key."""
    _unknown(data, LAYOUT_KEYS, source)
    buffers = data.get("buffers", {})
    if not isinstance(buffers, dict) or "color" not in buffers:
        raise InputError(f"{source}: needs at least [buffers.color] (where the noisy colour is)")
    layers: dict[str, tuple[str, ...]] = {}
    transforms: dict[str, Transform] = {}
    for buf, entry in buffers.items():
        if buf not in BUFFER_CHANNELS:
            raise InputError(
                f"{source}: unknown buffer [buffers.{buf}]; buffers: {', '.join(BUFFER_CHANNELS)}"
            )
        layers[buf], transform = _buffer_entry(buf, entry, f"{source}: buffers.{buf}")
        if transform is not None:
            transforms[buf] = transform
    required = tuple(_strings(data.get("required", ["color"]), f"{source}: required"))
    missing = [b for b in required if b not in layers]
    if missing:
        raise InputError(f"{source}: required buffer {missing[0]!r} has no [buffers.{missing[0]}]")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise InputError(f"{source}: description: expected a string")
    return Layout(name, description, layers, transforms, required)


def load_layout(path: str | os.PathLike) -> Layout:
    """Read a layout file (TOML, docs/layouts.md); its name is the file's stem."""
    path = Path(path).expanduser()
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such layout file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{path}: not a readable TOML layout file: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and tables recursively
        raise InputError(
            f"{path}: not a readable TOML layout file: nested too deep (a layout has two levels)"
        ) from None
    layout = parse_layout(data, path.stem, str(path))
    return Layout(**{**layout.__dict__, "path": path})


def preset_paths() -> dict[str, Path]:
    """The shipped presets: name -> TOML file (`canonical` first)."""
    paths = {p.stem: p for p in sorted(LAYOUTS_DIR.glob("*.toml"))}
    return dict(sorted(paths.items(), key=lambda kv: kv[0] != "canonical"))


LAYOUTS: dict[str, Layout] = {name: load_layout(p) for name, p in preset_paths().items()}


def get_layout(name: str | os.PathLike) -> Layout:
    """A preset by name (``canonical``, ``blender``) or a layout file (``.toml``)."""
    text = os.fspath(name)
    if text in LAYOUTS:
        return LAYOUTS[text]
    if text.lower().endswith(".toml") or os.sep in text or Path(text).is_file():
        return load_layout(text)
    raise InputError(
        f"unknown layout {text!r}; known layouts: {', '.join(LAYOUTS)}, or a layout file "
        "(.toml, docs/layouts.md)"
    )


def layout_fingerprint(layout: Layout) -> str:
    """What a cache entry or an output records of the layout it was read through: a preset's
    name (its file is the package's), else the name and the sha256 of the layout's file."""
    if layout.path is None or Path(layout.path).parent == LAYOUTS_DIR:
        return layout.name
    return f"{layout.name}:{hashlib.sha256(Path(layout.path).read_bytes()).hexdigest()}"


def parse_overrides(items: Iterable[str] | None) -> dict[str, str]:
    """Parse ``BUFFER=VALUE`` strings (``--channel``) into a dict; InputError on bad syntax."""
    overrides: dict[str, str] = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise InputError(
                f"bad --channel {item!r}: expected BUFFER=CHANNELS, e.g. albedo=MyLayer.Albedo"
            )
        if key not in BUFFER_CHANNELS:
            raise InputError(
                f"bad --channel {item!r}: unknown buffer {key!r}; buffers: "
                + ", ".join(BUFFER_CHANNELS)
            )
        if key in overrides:
            raise InputError(f"bad --channel {item!r}: buffer {key!r} given twice")
        if "," in value:
            names = [v.strip() for v in value.split(",")]
            if len(names) != BUFFER_CHANNELS[key] or not all(names):
                raise InputError(
                    f"bad --channel {item!r}: {key} needs {BUFFER_CHANNELS[key]} channel names"
                )
        overrides[key] = value
    return overrides


def _list_names(names: Iterable[str], limit: int = 40) -> str:
    names = sorted(names)
    shown = ", ".join(names[:limit])
    return shown + (f", ... (+{len(names) - limit} more)" if len(names) > limit else "")


def _lookup(full: str, present: set[str], by_suffix: dict[str, list[str]]) -> list[str]:
    """Channels named `full` exactly, else the ones named `<prefix>.full`."""
    if full in present:
        return [full]
    return by_suffix.get(full, [])


def _suffix_index(present: Iterable[str]) -> dict[str, list[str]]:
    """Map every dotted suffix of a channel name to the names that end with it."""
    index: dict[str, list[str]] = {}
    for name in present:
        parts = name.split(".")
        for i in range(1, len(parts)):
            index.setdefault(".".join(parts[i:]), []).append(name)
    return index


def _resolve_layer(
    layer: str,
    channels: int,
    present: set[str],
    by_suffix: dict[str, list[str]],
    source: str,
) -> tuple[list[str] | None, list[str]]:
    """Channel names for `layer`, or (None, missing names of the best partial match).
    A `layer` with commas lists the exact channel names."""
    if "," in layer:
        names = [n.strip() for n in layer.split(",")]
        missing = [n for n in names if n not in present]
        return (None, missing) if missing else (names, [])
    sets: list[tuple[str, ...]] = []
    if channels == 1 and layer:
        sets.append(("",))  # the layer names a channel itself
    sets.extend(COMPONENT_SETS[channels])
    best_missing: list[str] = []
    best_found = 0
    for comps in sets:
        fulls = [".".join(p for p in (layer, c) if p) for c in comps]
        if not layer:  # bare names: exact matches only
            hits = [[f] if f in present else [] for f in fulls]
        else:
            hits = [_lookup(f, present, by_suffix) for f in fulls]
        found = sum(1 for h in hits if h)
        if found == len(fulls):
            prefixes = {h[0][: len(h[0]) - len(f)] for h, f in zip(hits, fulls, strict=True)}
            if any(len(h) > 1 for h in hits) or len(prefixes) > 1:
                ambiguous = sorted({n for h in hits for n in h})
                raise InputError(
                    f"{source}: layer {layer!r} is ambiguous: {_list_names(ambiguous, 8)}; "
                    "name it with its prefix (--channel BUFFER=Prefix.Layer)"
                )
            return [h[0] for h in hits], []
        if found > best_found:
            best_found = found
            best_missing = [f for h, f in zip(hits, fulls, strict=True) if not h]
    return None, best_missing


def _suggest(layout: Layout, buf: str, present: set[str], by_suffix: dict[str, list[str]]) -> str:
    """', try --layout X' when another layout finds `buf` in these channels."""
    for other in LAYOUTS.values():
        if other.name == layout.name:
            continue
        for layer in other.layers.get(buf, ()):
            try:
                names, _ = _resolve_layer(layer, BUFFER_CHANNELS[buf], present, by_suffix, "")
            except InputError:  # ambiguous there too: still the right layout
                names = [layer]
            if names:
                return f", try --layout {other.name}"
    return ""


def resolve_channels(
    channel_names: Iterable[str],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    source: str = "<file>",
    *,
    buffers: Collection[str] | None = None,
    required: Collection[str] = (),
) -> dict[str, list[str]]:
    """Map each canonical buffer found in a file to its EXR channel names (in order).

    Buffers absent from the file are left out, except required ones (`color`, every
    overridden buffer and those in `required`), which raise InputError naming `source`,
    the missing channels and the channels present.
    buffers: resolve only these buffers, the required ones and the overridden ones (None:
        every canonical buffer), so that a layer nobody reads cannot fail the file.
    """
    layout = get_layout(layout) if isinstance(layout, str) else layout
    overrides = dict(overrides or {})
    present = set(channel_names)
    by_suffix = _suffix_index(present)
    result: dict[str, list[str]] = {}
    for buf, nch in BUFFER_CHANNELS.items():
        value = overrides.get(buf)
        if value is not None and value.lower() == "none":
            continue
        required_here = buf in layout.required or value is not None or buf in required
        if not required_here and buffers is not None and buf not in buffers:
            continue
        layers: Sequence[str] = (value,) if value is not None else layout.layers.get(buf, ())
        partial: list[str] = []
        for layer in layers:
            names, missing = _resolve_layer(layer, nch, present, by_suffix, source)
            if names is not None:
                result[buf] = names
                break
            partial = partial or missing
        else:
            if partial or (required_here and layers):
                if not partial:
                    comps = COMPONENT_SETS[nch][0]
                    partial = [".".join(p for p in (layers[0], c) if p) for c in comps]
                raise InputError(
                    f"{source}: missing channel {', '.join(partial)} for buffer {buf!r} "
                    f"(layout {layout.name}{_suggest(layout, buf, present, by_suffix)}); "
                    f"channels present: {_list_names(present)}{_hint(buf)}"
                )
            if required_here:
                raise InputError(f"{source}: layout {layout.name} has no source for {buf!r}")
    return result


# What a buffer is and how to make it, for the buffers most renderers do not write.
BUFFER_HINTS = {
    "color_b": (
        "color_b is a second, independent estimate of the same frame (Choi24's cross-regression "
        "needs two): render each frame twice with different seeds (Cycles: Sampling > Seed), "
        "half the samples each, and store the second render's RGB in the same EXR as "
        "colorB.R/G/B, or name its layer with --channel color_b=LAYER"
    ),
}


def _hint(buf: str) -> str:
    return f"; {BUFFER_HINTS[buf]}" if buf in BUFFER_HINTS else ""


def check_channels(
    channel_names: Iterable[str],
    mapping: Mapping[str, Sequence[str]],
    layout: Layout,
    source: str = "<file>",
) -> None:
    """InputError naming `source`, the buffer and its missing channels when a file lacks a
    channel of `mapping` (a mapping resolved from another file of the same sequence)."""
    present = set(channel_names)
    for buf, names in mapping.items():
        missing = [n for n in names if n not in present]
        if missing:
            raise InputError(
                f"{source}: missing channel {', '.join(missing)} for buffer {buf!r} "
                f"(layout {layout.name}, as the sequence's first frame has it); "
                f"channels present: {_list_names(present)}{_hint(buf)}"
            )


def stack_buffers(
    channels: Mapping[str, np.ndarray],
    mapping: Mapping[str, Sequence[str]],
    source: str = "<file>",
) -> Buffers:
    """Stack the mapped channels into (C, H, W) float32 buffers (no conversion).

    One copy per buffer, converting from the file's type (e.g. float16) on the way.
    Raises InputError when the selected channels differ in size.
    """
    buffers: Buffers = {}
    first: str | None = None
    for buf, names in mapping.items():
        for name in names:
            if first is None:
                first = name
            elif np.shape(channels[name]) != np.shape(channels[first]):
                (h, w), (h0, w0) = np.shape(channels[name]), np.shape(channels[first])
                raise InputError(
                    f"{source}: channel {name!r} is {w}x{h} but channel {first!r} is {w0}x{h0}"
                )
        buffers[buf] = np.stack([channels[n] for n in names], dtype=np.float32)
    return buffers


def extract_buffers(
    channels: Mapping[str, np.ndarray],
    layout: Layout | str = "canonical",
    overrides: Mapping[str, str] | None = None,
    source: str = "<file>",
    *,
    buffers: Collection[str] | None = None,
) -> Buffers:
    """Stack a file's channels into canonical (C, H, W) float32 buffers (no conversion).

    buffers: only these (and `color`, always required); None: every buffer the file has.
    Raises InputError when the selected channels differ in size.
    """
    mapping = resolve_channels(channels.keys(), layout, overrides, source, buffers=buffers)
    if buffers is not None:
        mapping = {b: names for b, names in mapping.items() if b in buffers or b == "color"}
    return stack_buffers(channels, mapping, source)
