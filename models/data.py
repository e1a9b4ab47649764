"""Training data: whole sequences in memory -> batches of randomly cropped, flipped clips.

A sequence is a folder in the canonical EXR layout (docs/contract.md, "EXR layout"):
`frame_NNNN.exr` and `ref_NNNN.exr`. A training sample is a clip of F consecutive frames of
one sequence with one random crop, flip and brightness factor shared by all its frames
(Lee24 IV-B: random 128 x 128 crops, horizontal / vertical flips, brightness in [0.8, 1.2]).

Flips keep the buffers' meaning: a horizontal flip negates motion.x and normal.x, a
vertical flip motion.y and normal.y (screen-space conventions: x right, y down for motion).

Per-sample input (the rank-5 `samples` buffer, (T, S, C, H, W) in memory): its features are
named by the model's config (runtime/sequences/samples.py); flips negate the x / y of its
normals, the brightness factor scales its radiance, and `sample_counts` (e.g. (1, 2, 4); Isik21
4.3 takes them round robin per epoch, here one is drawn per batch, which a resumed run
reproduces) keeps a random subset of S samples of every clip of a batch.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from rtdenoise.runtime.contract import RADIANCE_BUFFERS, SAMPLES, SCREEN_XY_BUFFERS
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.frames import (
    find_frames,
    find_reference,
    read_frame,
    read_reference,
)
from rtdenoise.runtime.sequences.samples import radiance_channels, signed_channels

# Buffers whose x / y components flip sign with the image (channel 0 = x, 1 = y), and the
# ones that carry radiance (scaled by the brightness augmentation with the reference).
SIGNED_BUFFERS = SCREEN_XY_BUFFERS


@dataclass
class SequenceData:
    """One sequence in memory: buffers name -> (T, C, H, W) and reference (T, 3, H, W)."""

    name: str
    buffers: dict[str, np.ndarray]
    reference: np.ndarray

    @property
    def frames(self) -> int:
        return int(self.reference.shape[0])

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return int(self.reference.shape[2]), int(self.reference.shape[3])


def load_sequence(
    folder: str | os.PathLike,
    buffers: Sequence[str],
    sample_features: Sequence[str] | None = None,
) -> SequenceData:
    """Read every frame (only the named buffers) and its reference into memory.

    `samples` among the buffers is read with the per-sample features `sample_features`.
    Raises InputError naming the file for a missing buffer, reference or a size mismatch.
    """
    folder = Path(folder)
    paths = find_frames(folder)
    stacks: dict[str, list[np.ndarray]] = {name: [] for name in buffers}
    refs: list[np.ndarray] = []
    size: tuple[int, int] | None = None
    features = sample_features if SAMPLES in buffers else None
    for i, path in enumerate(paths):
        frame = read_frame(path, expect_size=size, index=i, sample_features=features)
        size = frame.size
        for name in buffers:
            if name not in frame.buffers:
                raise InputError(
                    f"{path}: buffer {name!r} is missing (present: {sorted(frame.buffers)})"
                )
            stacks[name].append(frame.buffers[name])
        ref_path = find_reference(path)
        if ref_path is None:
            raise InputError(f"{path}: no reference ref_NNNN.exr beside it (needed for training)")
        refs.append(read_reference(ref_path, expect_size=size))
    return SequenceData(
        name=folder.name,
        buffers={name: np.stack(arrs).astype(np.float32) for name, arrs in stacks.items()},
        reference=np.stack(refs).astype(np.float32),
    )


def load_sequences(
    folders: Sequence[str | os.PathLike],
    buffers: Sequence[str],
    sample_features: Sequence[str] | None = None,
) -> list[SequenceData]:
    """`load_sequence` for each folder; InputError if none is given."""
    if not folders:
        raise InputError("no training sequences given")
    return [load_sequence(f, buffers, sample_features) for f in folders]


def flip(
    buffers: dict[str, np.ndarray],
    reference: np.ndarray,
    horizontal: bool,
    vertical: bool,
    sample_features: Sequence[str] = (),
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Flip (..., C, H, W) arrays; negate the x (horizontal) / y (vertical) component of
    motion and normal (also the normals among the `sample_features` of `samples`) so that
    they still describe the flipped image."""
    axes = tuple(ax for ax, on in ((-1, horizontal), (-2, vertical)) if on)
    if not axes:
        return buffers, reference
    out = {}
    for name, arr in buffers.items():
        arr = np.flip(arr, axis=axes).copy()
        if name == SAMPLES:
            if not sample_features:
                raise InputError("flipping the samples buffer needs its sample features")
            xs, ys = signed_channels(sample_features)
        else:
            xs, ys = ([0], [1]) if name in SIGNED_BUFFERS else ([], [])
        for c in xs if horizontal else ():
            arr[..., c, :, :] *= -1.0
        for c in ys if vertical else ():
            arr[..., c, :, :] *= -1.0
        out[name] = arr
    return out, np.flip(reference, axis=axes).copy()


@dataclass
class Batch:
    """Clips as tensors: buffers name -> (B, T, C, h, w), reference (B, T, 3, h, w)."""

    buffers: dict[str, torch.Tensor]
    reference: torch.Tensor


class ClipSampler:
    """Draws batches of clips (same crop / flip / brightness for every frame of a clip).

    Clip length is min(frames, shortest sequence); crop size is min(crop, smallest frame
    side) rounded down to `multiple` (the model's pad_multiple). All randomness comes from
    `rng` (a numpy Generator), so a saved `rng.bit_generator.state` resumes the stream.
    """

    def __init__(
        self,
        sequences: Sequence[SequenceData],
        rng: np.random.Generator,
        *,
        frames: int = 8,
        crop: int = 128,
        batch: int = 4,
        multiple: int = 1,
        flips: bool = True,
        brightness: tuple[float, float] = (0.8, 1.2),
        sample_features: Sequence[str] = (),
        sample_counts: Sequence[int] = (),
    ) -> None:
        if not sequences:
            raise InputError("no training sequences given")
        self.sequences = list(sequences)
        self.rng = rng
        self.batch = int(batch)
        self.flips = flips
        self.brightness = (float(brightness[0]), float(brightness[1]))
        self.sample_features = tuple(sample_features)
        self.sample_counts = tuple(int(s) for s in sample_counts)
        if any(s < 1 for s in self.sample_counts):
            raise InputError(f"sample counts must be >= 1, got {list(self.sample_counts)}")
        self.frames = max(1, min(int(frames), min(s.frames for s in self.sequences)))
        side = min(int(crop), *(min(s.size) for s in self.sequences))
        self.crop = side - side % multiple
        if self.crop < multiple or self.crop < 1:
            raise InputError(
                f"frames of {min(min(s.size) for s in self.sequences)} px are too small for "
                f"crops that are multiples of {multiple}"
            )

    def clip(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """One clip: buffers name -> (T, C, crop, crop), reference (T, 3, crop, crop)."""
        rng = self.rng
        seq = self.sequences[int(rng.integers(len(self.sequences)))]
        t0 = int(rng.integers(seq.frames - self.frames + 1))
        h, w = seq.size
        y0 = int(rng.integers(h - self.crop + 1))
        x0 = int(rng.integers(w - self.crop + 1))
        flip_h = flip_v = False
        if self.flips:
            flip_h, flip_v = (bool(b) for b in rng.integers(2, size=2))
        scale = float(rng.uniform(*self.brightness))
        window = (
            slice(t0, t0 + self.frames),
            Ellipsis,
            slice(y0, y0 + self.crop),
            slice(x0, x0 + self.crop),
        )
        buffers = {name: arr[window] for name, arr in seq.buffers.items()}
        reference = seq.reference[window]
        buffers, reference = flip(buffers, reference, flip_h, flip_v, self.sample_features)
        if scale != 1.0:
            buffers = {name: self._brighter(name, arr, scale) for name, arr in buffers.items()}
            reference = reference * np.float32(scale)
        return buffers, reference

    def _brighter(self, name: str, arr: np.ndarray, scale: float) -> np.ndarray:
        if name in RADIANCE_BUFFERS:
            return arr * np.float32(scale)
        if name == SAMPLES:
            arr = arr.copy()
            arr[:, :, radiance_channels(self.sample_features)] *= np.float32(scale)
        return arr

    def _subsample(self, clips: list) -> None:
        """Give every clip the same number of samples (in place): a count drawn from
        sample_counts, or fewer if a clip has fewer (without sample_counts: the fewest any clip
        has); a random subset of each clip's samples."""
        if SAMPLES not in clips[0][0]:
            return
        have = [c[0][SAMPLES].shape[1] for c in clips]
        wanted = max(have)
        if self.sample_counts:
            wanted = self.sample_counts[int(self.rng.integers(len(self.sample_counts)))]
        count = min(wanted, *have)
        for (buffers, _), s in zip(clips, have, strict=True):
            if s != count:
                keep = np.sort(self.rng.choice(s, size=count, replace=False))
                buffers[SAMPLES] = np.ascontiguousarray(buffers[SAMPLES][:, keep])

    def sample(self) -> Batch:
        """A batch of `batch` clips as float32 tensors."""
        clips = [self.clip() for _ in range(self.batch)]
        self._subsample(clips)
        names = clips[0][0].keys()
        return Batch(
            buffers={
                n: torch.from_numpy(np.ascontiguousarray(np.stack([c[0][n] for c in clips])))
                for n in names
            },
            reference=torch.from_numpy(np.ascontiguousarray(np.stack([c[1] for c in clips]))),
        )
