"""Channel layouts: which EXR channels hold which canonical buffer, and their conventions.

A *layout* names, for every canonical buffer (docs/contract.md), the EXR layers it
may come from, tried in order, and a conversion to the canonical conventions
applied after reading. Two layouts ship:

- ``canonical`` (docs/contract.md, "Buffers"): ``R,G,B`` (noisy colour), ``colorB.R/G/B``,
  ``albedo.R/G/B``, ``normal.X/Y/Z``, ``depth.Z``, ``motion.X/Y``; no conversion.
- ``blender`` (Cycles multilayer, any view-layer prefix): ``Noisy Image`` (else
  ``Combined``), ``Denoising Albedo`` (clamped to [0, 1]), ``Denoising Normal``
  (camera space, kept as is), ``Denoising Depth.Z``, ``Vector.X/Y`` converted to
  our motion convention: previous = current + (Vector.X, -Vector.Y).

Channel matching (one rule for layouts and ``--channel`` overrides). A buffer
with C channels read from layer ``L`` uses the channels ``L.<c>`` for the first
component set that is complete: C = 3: ``R,G,B`` then ``X,Y,Z``; C = 2: ``X,Y``,
``R,G``, ``U,V``; C = 1: the channel ``L`` itself, then ``L.Z``, ``L.R``,
``L.Y``, ``L.V``. The empty layer ``""`` means bare names (``R``, ``G``, ``B``).
A name matches exactly or, failing that, with any one prefix
(``ViewLayer.L.<c>``); two prefixes holding the same layer is an error (name the
layer with its prefix to choose). A layer with only some of its channels is an
error naming the missing ones.

Overrides (``--channel BUFFER=VALUE``): VALUE is a layer name as above, a
comma-separated list of exactly C full channel names (``motion=mv.U,mv.V``), or
``none`` to ignore the buffer. An overridden buffer is required; the layout's
conversion still applies (the layout states the file's conventions).
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .contract import BUFFER_CHANNELS
from .errors import InputError

COMPONENT_SETS: dict[int, tuple[tuple[str, ...], ...]] = {
    3: (("R", "G", "B"), ("X", "Y", "Z")),
    2: (("X", "Y"), ("R", "G"), ("U", "V")),
    1: (("Z",), ("R",), ("Y",), ("V",)),
}

Buffers = dict[str, np.ndarray]


@dataclass(frozen=True)
class Layout:
    """Where each canonical buffer lives in a file and how to convert it."""

    name: str
    description: str
    layers: Mapping[str, tuple[str, ...]]  # buffer -> candidate layer names, tried in order
    convert: Callable[[Buffers], Buffers] = field(default=lambda b: b)
    required: tuple[str, ...] = ("color",)


def _convert_blender(buffers: Buffers) -> Buffers:
    """Cycles -> canonical conventions (research-notes, "Conventions in the wild")."""
    out = dict(buffers)
    if "motion" in out:
        # Blender's Vector.Y points up; rows are top-down: previous = current + (X, -Y).
        motion = out["motion"].copy()
        motion[1] *= -1.0
        out["motion"] = motion
    if "albedo" in out:
        # Denoising Albedo exceeds 1 where glossy surfaces reflect lights (tint x radiance).
        out["albedo"] = np.clip(out["albedo"], 0.0, 1.0)
    return out


LAYOUTS: dict[str, Layout] = {
    "canonical": Layout(
        name="canonical",
        description="R,G,B colour; colorB, albedo, normal (X,Y,Z), depth.Z, motion.X/Y "
        "(pixels, previous = current + motion, y down)",
        layers={
            "color": ("",),
            "color_b": ("colorB",),
            "albedo": ("albedo",),
            "normal": ("normal",),
            "depth": ("depth",),
            "motion": ("motion",),
        },
    ),
    "blender": Layout(
        name="blender",
        description="Cycles multilayer, any view-layer prefix: Noisy Image (else Combined), "
        "Denoising Albedo (clamped to [0,1]), Denoising Normal, Denoising Depth, "
        "Vector (motion = (X, -Y))",
        layers={
            "color": ("Noisy Image", "Combined"),
            "albedo": ("Denoising Albedo",),
            "normal": ("Denoising Normal",),
            "depth": ("Denoising Depth",),
            "motion": ("Vector",),
        },
        convert=_convert_blender,
    ),
}


def get_layout(name: str) -> Layout:
    """The layout called `name`; InputError listing the known ones otherwise."""
    try:
        return LAYOUTS[name]
    except KeyError:
        raise InputError(f"unknown layout {name!r}; known layouts: {', '.join(LAYOUTS)}") from None


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
    """Channel names for `layer`, or (None, missing names of the best partial match)."""
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
        if value is not None and "," in value:
            names = [v.strip() for v in value.split(",")]
            missing = [n for n in names if n not in present]
            if missing:
                raise InputError(
                    f"{source}: missing channel {', '.join(missing)} for buffer {buf!r}; "
                    f"channels present: {_list_names(present)}"
                )
            result[buf] = names
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
                    f"channels present: {_list_names(present)}"
                )
            if required_here:
                raise InputError(f"{source}: layout {layout.name} has no source for {buf!r}")
    return result


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
                f"channels present: {_list_names(present)}"
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
