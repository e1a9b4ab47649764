"""Host arrays in and out of a `Denoiser`: the layouts a renderer holds, half floats, padding.

Buffers come planar, (C, H, W) (or batched, (1, C, H, W); rank 5 `samples`: (S, C, H, W) or
(1, S, C, H, W)), or interleaved, (H, W, C) with an optional alpha channel that is ignored
((H, W) for one channel), in float32 or float16 (other real types are converted). The model
reads them planar float32, batched, replicate-padded by its edge margin on every side and
to its pad multiple. The output follows
the layout of `color`, or fills the caller's `out` (float16 clamped to the half range).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .contract import HALF_MAX, BufferSpec
from .errors import InputError


def is_interleaved(a: np.ndarray, channels: int | None, channels_last: bool | None) -> bool:
    """Whether `a` is (H, W, C), (H, W, C + 1) or, for C = 1, (H, W); planar wins a tie."""
    if channels is None or channels_last is False:
        return False
    fits = (a.ndim == 3 and a.shape[-1] in (channels, channels + 1)) or (
        a.ndim == 2 and channels == 1
    )
    if channels_last:
        return fits
    planar = a.ndim in (3, 4) and a.shape[-3] == channels
    return fits and not planar


def batched_planar(
    spec: BufferSpec, a: np.ndarray, channels_last: bool | None = None
) -> np.ndarray:
    """(C, H, W) or (1, C, H, W) [rank 5: (S, C, H, W) or (1, S, C, H, W)], or interleaved
    (H, W, C[+1]) / (H, W) -> the batched planar view; InputError naming the buffer if unfit."""
    given = a.shape
    good = a.dtype.kind in "fiu"
    if good and spec.rank == 4 and is_interleaved(a, spec.channels, channels_last):
        a = (a[..., None] if a.ndim == 2 else a[..., : spec.channels]).transpose(2, 0, 1)
    if good and a.ndim == spec.rank - 1:
        a = a[None]
    good = good and a.ndim == spec.rank and a.shape[0] == 1
    good = good and (spec.channels is None or a.shape[-3] == spec.channels)
    good = good and min(a.shape[-2:], default=0) > 0
    if not good:
        batched = spec.expected.replace("(", "(1, ", 1)
        interleaved = "(H, W)" if spec.channels == 1 else f"(H, W, {spec.channels}[+alpha])"
        raise InputError(
            f"buffer {spec.name!r} has shape {given} and dtype {a.dtype}; expected "
            f"{spec.expected}, {batched} or {interleaved}, float32 or float16"
        )
    return a


def planar_frame(
    specs: Sequence[BufferSpec],
    buffers: Mapping[str, np.ndarray],
    channels_last: bool | None,
    family: str,
) -> tuple[dict[str, np.ndarray], list[str], tuple[int, int]]:
    """The buffers `specs` name as batched planar float32 (one copy for interleaved or half
    buffers), the names of those that are copies (free to fix in place), and (H, W)."""
    if not isinstance(buffers, Mapping):
        raise InputError(f"process() takes a dict name -> array, got {type(buffers).__name__}")
    missing = [s.name for s in specs if s.name not in buffers]
    if missing:
        given = ", ".join(sorted(map(str, buffers))) or "none"
        raise InputError(
            f"missing buffer {missing[0]!r}: model {family!r} needs "
            f"{', '.join(s.name for s in specs)}; given: {given}"
        )
    arrays: dict[str, np.ndarray] = {}
    size: tuple[int, int] | None = None
    for spec in specs:
        a = batched_planar(spec, np.asarray(buffers[spec.name]), channels_last)
        if size is None:
            size, first = a.shape[-2:], spec.name
        elif a.shape[-2:] != size:
            raise InputError(
                f"buffer {spec.name!r} has shape {np.shape(buffers[spec.name])}; expected "
                f"H x W = {size[0]} x {size[1]} like {first!r}"
            )
        arrays[spec.name] = a
    if size is None:  # a model that reads no buffers cannot tell the frame size
        raise InputError(f"model {family!r} lists no input buffers")
    converted: dict[str, np.ndarray] = {}
    owned = []
    for name, a in arrays.items():
        a32 = np.ascontiguousarray(a, dtype=np.float32)
        if not np.may_share_memory(a32, np.asarray(buffers[name])):
            owned.append(name)  # a converted copy: the guard may fix it in place
        converted[name] = a32
    return converted, owned, (int(size[0]), int(size[1]))


def padded_size(size: tuple[int, int], multiple: int, margin: int = 0) -> tuple[int, int]:
    """(H, W) with `margin` pixels on every side, rounded up to multiples of `multiple`."""
    h, w = size[0] + 2 * margin, size[1] + 2 * margin
    return -(-h // multiple) * multiple, -(-w // multiple) * multiple


def pad_edge(a: np.ndarray, hp: int, wp: int, margin: int = 0) -> np.ndarray:
    """Replicate-pad the last two axes of `a` to (hp, wp): `margin` pixels on the top and left,
    the rest on the bottom and right (the frame's edge pixels repeated); `a` if no pad."""
    h, w = a.shape[-2:]
    if (h, w) == (hp, wp):
        return a
    m = margin
    out = np.empty(a.shape[:-2] + (hp, wp), np.float32)
    out[..., m : m + h, m : m + w] = a
    out[..., m : m + h, :m] = a[..., :, :1]
    out[..., m : m + h, m + w :] = a[..., :, w - 1 : w]
    out[..., :m, :] = out[..., m : m + 1, :]
    out[..., m + h :, :] = out[..., m + h - 1 : m + h, :]
    return out


def output_view(out: np.ndarray, size: tuple[int, int], channels_last: bool | None) -> np.ndarray:
    """The (3, H, W) view of a caller's output array that `store` fills; InputError if unfit."""
    h, w = size
    if not isinstance(out, np.ndarray) or out.dtype not in (np.float32, np.float16):
        kind = out.dtype if isinstance(out, np.ndarray) else type(out).__name__
        raise InputError(f"out must be a float32 or float16 numpy array, got {kind}")
    if not out.flags.writeable:  # refused now: after the run the frame's history would be lost
        raise InputError(
            f"out is a read-only array (shape {out.shape}, {out.dtype}); pass a writable one"
        )
    if out.shape[:2] == (h, w) and is_interleaved(out, 3, channels_last):
        return out[..., :3].transpose(2, 0, 1)
    if out.shape == (3, h, w) and channels_last is not True:
        return out
    raise InputError(
        f"out has shape {out.shape}; expected (3, {h}, {w}), ({h}, {w}, 3) or ({h}, {w}, 4)"
    )


def store(target: np.ndarray, planar: np.ndarray) -> None:
    """Write a (3, H, W) float32 frame into the caller's view, clamping to the half range."""
    if target.dtype == np.float16:
        np.clip(planar, -HALF_MAX, HALF_MAX, out=target, casting="same_kind")
    else:
        np.copyto(target, planar)


def returned_frame(
    frame: np.ndarray, color: np.ndarray | None, channels_last: bool | None, cropped: bool
) -> np.ndarray:
    """What `process` returns without `out`: (H, W, 3) when `color` came interleaved, else the
    (3, H, W) frame (made contiguous when it is a crop of the padded output)."""
    if color is not None and is_interleaved(np.asarray(color), 3, channels_last):
        return np.ascontiguousarray(frame.transpose(1, 2, 0))
    return np.ascontiguousarray(frame) if cropped else frame
