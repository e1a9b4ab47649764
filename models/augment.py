"""Geometric and colour augmentation of clips that keeps every buffer's meaning.

A `Transform` is a mirror (horizontal / vertical flip), then a rotation by quarter turns, then
a permutation of the colour channels, applied alike to every frame of a clip, every buffer and
the reference (arrays (..., C, H, W); the rank-5 `samples` buffer (T, S, C, H, W) too).

Conventions (docs/contract.md, "Buffers"; datagen/features.py, runtime/sequences/layouts.py):

- `motion`: pixels, previous = current + motion, x right, **y down** (image rows).
- `normal`: **camera space**, x right, **y up**, z towards the camera (Mitsuba renders and
  Blender's Denoising Normal alike). Mirroring or rotating the image about the view axis is
  mirroring or rotating the camera, so x / y transform with the image and z is unchanged.
- `depth`: view depth, unchanged by any of these.

The vector rules, with image coordinates (x right, y down) and `np.rot90(a, k=1, axes=(-2,
-1))` (a quarter turn counter-clockwise as displayed: pixel (x, y) of a W-wide image moves to
(y, W - 1 - x)):

- horizontal flip: x -> -x; vertical flip: y -> -y (either y convention);
- quarter turn: a y-down vector (dx, dy) -> (dy, -dx); a y-up vector (nx, ny) -> (-ny, nx).

Colour permutation (OIDN's channel-permutation augmentation): the same permutation of R, G, B
for `color`, `color_b`, `albedo`, the reference and the radiance / albedo features of every
sample. Normals are camera-space, so their channels are NOT permuted (OIDN permutes normal
channels because its normals may be world-space, where any axis order is another valid frame;
in camera space z is the view axis and x / y follow the image).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rtdenoise.runtime.contract import SAMPLES
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.samples import feature_offsets

# Screen-space 2D vectors in a buffer's channels 0 and 1, and whether their y points down.
Y_DOWN_VECTORS = ("motion",)
Y_UP_VECTORS = ("normal",)
# Buffers whose three channels are R, G, B (permuted by a colour permutation).
COLOUR_BUFFERS = ("color", "color_b", "albedo")
IDENTITY = (0, 1, 2)


@dataclass(frozen=True)
class Transform:
    """Flip(s), then `rotation` quarter turns counter-clockwise (np.rot90 on (H, W)), then the
    colour permutation `permutation` (output channel i = input channel permutation[i])."""

    flip_h: bool = False
    flip_v: bool = False
    rotation: int = 0
    permutation: tuple[int, int, int] = IDENTITY

    @property
    def geometric(self) -> bool:
        return self.flip_h or self.flip_v or self.rotation % 4 != 0

    @property
    def identity(self) -> bool:
        return not self.geometric and tuple(self.permutation) == IDENTITY


def _layout(
    name: str, sample_features: Sequence[str]
) -> tuple[list[tuple[int, int, bool]], list[int]]:
    """([(x channel, y channel, y_down)], [first channel of each RGB triple]) of a buffer."""
    if name == SAMPLES:
        if not sample_features:
            raise InputError("transforming the samples buffer needs its sample features")
        off = feature_offsets(sample_features)
        vectors = [(off[f], off[f] + 1, f in Y_DOWN_VECTORS) for f in sample_features
                   if f in Y_DOWN_VECTORS + Y_UP_VECTORS]  # fmt: skip
        return vectors, [off[f] for f in sample_features if f in COLOUR_BUFFERS]
    if name in Y_DOWN_VECTORS or name in Y_UP_VECTORS:
        return [(0, 1, name in Y_DOWN_VECTORS)], []
    return [], [0] if name in COLOUR_BUFFERS else []


def _quarter_turns(x: np.ndarray, y: np.ndarray, k: int, y_down: bool):
    """Vector components (x, y) after k quarter turns counter-clockwise as displayed."""
    for _ in range(k % 4):
        x, y = (y, -x) if y_down else (-y, x)
    return x, y


def _transform_array(
    arr: np.ndarray,
    t: Transform,
    vectors: Sequence[tuple[int, int, bool]],
    colours: Sequence[int],
) -> np.ndarray:
    axes = tuple(ax for ax, on in ((-1, t.flip_h), (-2, t.flip_v)) if on)
    out = np.flip(arr, axis=axes) if axes else arr
    if t.rotation % 4:
        out = np.rot90(out, k=t.rotation % 4, axes=(-2, -1))
    # one owned, contiguous float32 copy (also of a memory-mapped float16 view) for the edits
    out = np.array(out, dtype=np.float32, copy=True)
    for cx, cy, y_down in vectors:
        x, y = out[..., cx, :, :].copy(), out[..., cy, :, :].copy()
        if t.flip_h:
            x *= -1.0
        if t.flip_v:
            y *= -1.0
        x, y = _quarter_turns(x, y, t.rotation, y_down)
        out[..., cx, :, :], out[..., cy, :, :] = x, y
    if tuple(t.permutation) != IDENTITY:
        for c in colours:
            out[..., c : c + 3, :, :] = out[..., [c + p for p in t.permutation], :, :]
    return out


def apply_transform(
    buffers: Mapping[str, np.ndarray],
    reference: np.ndarray,
    transform: Transform,
    sample_features: Sequence[str] = (),
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """`transform` applied to every buffer (by its meaning, see the module docstring) and to
    the reference (an RGB image); new float32 arrays (the inputs unchanged when `transform` is
    the identity). An odd number of quarter turns swaps H and W."""
    if transform.identity:
        return dict(buffers), reference
    out = {}
    for name, arr in buffers.items():
        vectors, colours = _layout(name, sample_features)
        out[name] = _transform_array(arr, transform, vectors, colours)
    return out, _transform_array(reference, transform, [], [0])


def permutations() -> list[tuple[int, int, int]]:
    """The 6 permutations of (R, G, B), identity first (what a random draw picks from)."""
    return [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]


__all__ = [
    "COLOUR_BUFFERS",
    "IDENTITY",
    "Transform",
    "Y_DOWN_VECTORS",
    "Y_UP_VECTORS",
    "apply_transform",
    "permutations",
]
