"""Training data: sequences (in memory or memory-mapped) -> batches of augmented clips.

A sequence is a folder of `frame_NNNN.exr` and `ref_NNNN.exr`, in the canonical EXR layout
(docs/contract.md, "EXR layout") or in any layout `denoise-run` reads (a preset such as
`blender` or a layout file, runtime/sequences/layouts.py), converted at load time the same way.
A training sample is a clip of F consecutive frames of one sequence with one random crop,
augmentation and brightness factor shared by all its frames (Lee24 IV-B: random 128 x 128
crops, horizontal / vertical flips, brightness in [0.8, 1.2];
Isik21 4.3 and Fan21's official code add 90-degree rotations; Open Image Denoise permutes the
colour channels). The geometric and colour rules are models/augment.py's: flips and quarter
turns transform motion and camera-space normals with the image, depth is unchanged, a colour
permutation applies alike to color, color_b, albedo, the reference and the samples' colours.

Exposure (`exposure="auto"`): each clip's radiance and reference are scaled by the
auto-exposure of its noisy colour (models/transfer.py: key 0.18 / geometric mean of block
luminance), before the brightness factor. The ONNX contract feeds raw renderer radiance and the
shipped families tonemap inside the graph (log1p, gamma), so they are scale-dependent and a
model trained only on normalised clips would see other scales at run time: "auto" is meant
with a wide --brightness range around it (the scales a renderer produces), and "none" (raw
values, the default) is what every shipped demo was trained with.

Per-sample input (the rank-5 `samples` buffer, (T, S, C, H, W) in memory): its features are
named by the model's config (runtime/sequences/samples.py); the augmentation treats its normals and
colours like the pixel buffers, the brightness factor scales its radiance, and
`sample_counts` (e.g. (1, 2, 4); Isik21 4.3 takes them round robin per epoch, here one is drawn
per batch, which a resumed run reproduces) keeps a random subset of S samples of every clip of
a batch.

Sequences live in memory as float32 (`load_sequences`), or, with a cache folder, as
memory-mapped .npy files (models/cache.py) that the operating system pages in per crop, for
training sets larger than memory.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping, Sequence
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
    shot_cuts,
)
from rtdenoise.runtime.sequences.layouts import Layout, get_layout
from rtdenoise.runtime.sequences.samples import radiance_channels

from .augment import Transform, apply_transform, permutations
from .transfer import autoexposure

# Buffers whose x / y components flip sign with the image (channel 0 = x, 1 = y), and the
# ones that carry radiance (scaled by the brightness augmentation with the reference).
SIGNED_BUFFERS = SCREEN_XY_BUFFERS
EXPOSURES = ("none", "auto")


@dataclass
class SequenceData:
    """One sequence: buffers name -> (T, C, H, W) and reference (T, 3, H, W), float32 arrays
    in memory or memory-mapped float16 / float32 arrays (models/cache.py)."""

    name: str
    buffers: dict[str, np.ndarray]
    reference: np.ndarray
    cuts: tuple[int, ...] = ()  # frames that start a new shot (runtime frames.shot_cuts)

    def clip_starts(self, length: int) -> list[int]:
        """First frames of the `length`-frame clips that cross no cut (a clip may start at
        one: its first frame resets the history anyway)."""
        return [
            t0
            for t0 in range(self.frames - length + 1)
            if not any(t0 < c < t0 + length for c in self.cuts)
        ]

    @property
    def frames(self) -> int:
        return int(self.reference.shape[0])

    @property
    def size(self) -> tuple[int, int]:
        """(height, width)."""
        return int(self.reference.shape[2]), int(self.reference.shape[3])

    def frame(self, i: int) -> dict[str, np.ndarray]:
        """Frame `i`'s buffers as float32 arrays (what the frame loop reads)."""
        return {n: np.asarray(a[i], dtype=np.float32) for n, a in self.buffers.items()}

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays (on disk for a memory-mapped sequence)."""
        return sum(a.nbytes for a in self.buffers.values()) + self.reference.nbytes


def load_sequence(
    folder: str | os.PathLike,
    buffers: Sequence[str],
    sample_features: Sequence[str] | None = None,
    layout: Layout | str = "canonical",
) -> SequenceData:
    """Read every frame (only the named buffers) and its reference into memory.

    `samples` among the buffers is read with the per-sample features `sample_features`;
    `layout` (a preset name, a layout file or a Layout) maps the files' channels, as in
    `denoise-run --layout`.
    Raises InputError naming the file for a missing buffer, reference or a size mismatch.
    """
    folder = Path(folder)
    paths = find_frames(folder)
    stacks: dict[str, list[np.ndarray]] = {name: [] for name in buffers}
    refs: list[np.ndarray] = []
    size: tuple[int, int] | None = None
    features = sample_features if SAMPLES in buffers else None
    layout = get_layout(layout) if isinstance(layout, str) else layout
    for i, path in enumerate(paths):
        frame = read_frame(path, layout, expect_size=size, index=i, sample_features=features)
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
        refs.append(read_reference(ref_path, layout, expect_size=size))
    return SequenceData(
        name=folder.name,
        buffers={name: np.stack(arrs).astype(np.float32) for name, arrs in stacks.items()},
        reference=np.stack(refs).astype(np.float32),
        cuts=shot_cuts(folder),
    )


def sequence_kind(folder: str | os.PathLike) -> str | None:
    """The scene kind a rendered sequence's meta.json names (denoise-render writes it), or
    None without one."""
    path = Path(folder) / "meta.json"
    try:
        kind = json.loads(path.read_text()).get("kind")
    except (OSError, ValueError, AttributeError):
        return None
    return kind if isinstance(kind, str) else None


def _holds_frames(folder: Path) -> bool:
    return any(p.suffix.lower() == ".exr" for p in folder.iterdir())


def training_folders(paths: Sequence[str | os.PathLike]) -> tuple[list[Path], list[Path]]:
    """The sequence folders `paths` name: a folder holding EXR frames is one; a folder of
    sequence folders (a set denoise-render writes, e.g. train_v2/) stands for its complete
    ones, sorted by name. Returns (sequences, incomplete): a set's sub-folder without
    meta.json (denoise-render writes it last) is still rendering or was killed, and is left
    out. InputError for a path that is neither."""
    sequences: list[Path] = []
    incomplete: list[Path] = []
    for given in paths:
        path = Path(given)
        if not path.is_dir():
            raise InputError(f"{path}: no such sequence folder")
        if _holds_frames(path):
            sequences.append(path)
            continue
        subs = sorted(q for q in path.iterdir() if q.is_dir() and _holds_frames(q))
        if not subs:
            raise InputError(
                f"{path}: neither a sequence (no EXR frames) nor a set of sequence folders"
            )
        for sub in subs:
            (sequences if (sub / "meta.json").is_file() else incomplete).append(sub)
    return sequences, incomplete


def oversampled(folders: Sequence[Path], factors: Mapping[str, int]) -> list[Path]:
    """`folders` with each one of a kind in `factors` (meta.json `kind` -> N) listed N times,
    so that clips of that kind are drawn N times as often. InputError for a kind no folder
    has (a typo would otherwise train on the plain mix silently)."""
    if not factors:
        return list(folders)
    kinds = [sequence_kind(f) for f in folders]
    missing = sorted(set(factors) - set(kinds))
    if missing:
        present = sorted({k for k in kinds if k is not None})
        raise InputError(
            f"oversample: no training sequence has kind {', '.join(map(repr, missing))} "
            f"(meta.json kinds present: {', '.join(present) or 'none'})"
        )
    return [f for f, k in zip(folders, kinds, strict=True) for _ in range(factors.get(k, 1))]


def available_memory() -> int | None:
    """Bytes of memory available to new allocations (Linux MemAvailable), None elsewhere."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


# In-memory loading refuses a training set estimated above this share of the available memory.
MEMORY_SHARE = 0.5


def load_sequences(
    folders: Sequence[str | os.PathLike],
    buffers: Sequence[str],
    sample_features: Sequence[str] | None = None,
    cache: str | os.PathLike | None = None,
    layout: Layout | str = "canonical",
) -> list[SequenceData]:
    """`load_sequence` for each folder, or with `cache` (a folder) each sequence converted once
    to .npy files there and memory-mapped (models/cache.py); InputError if none is given.

    In memory, the first sequence's size times their number is checked against the available
    memory first: above MEMORY_SHARE of it, InputError asks for a cache folder instead of
    letting the kernel kill the run after minutes of reading.
    """
    if not folders:
        raise InputError("no training sequences given")
    # a folder listed more than once (oversampling) is read once and shared
    unique = list(dict.fromkeys(Path(f).resolve() for f in folders))
    if cache is not None:
        from .cache import cached_sequence

        loaded = [cached_sequence(f, buffers, sample_features, cache, layout) for f in unique]
    else:
        first = load_sequence(unique[0], buffers, sample_features, layout)
        estimate, free = first.nbytes * len(unique), available_memory()
        if free is not None and estimate > MEMORY_SHARE * free:
            raise InputError(
                f"{len(unique)} sequences like {folders[0]} need about "
                f"{estimate / 2**30:.1f} GiB as float32 in memory, {free / 2**30:.1f} GiB are "
                f"available: give a cache folder (denoise-train --cache DIR) to memory-map them "
                f"instead"
            )
        rest = (load_sequence(f, buffers, sample_features, layout) for f in unique[1:])
        loaded = [first, *rest]
    by_path = dict(zip(unique, loaded, strict=True))
    return [by_path[Path(f).resolve()] for f in folders]


def flip(
    buffers: dict[str, np.ndarray],
    reference: np.ndarray,
    horizontal: bool,
    vertical: bool,
    sample_features: Sequence[str] = (),
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Flip (..., C, H, W) arrays; negate the x (horizontal) / y (vertical) component of
    motion and normal (also the normals among the `sample_features` of `samples`) so that
    they still describe the flipped image (models/augment.py, a Transform of flips only)."""
    return apply_transform(buffers, reference, Transform(horizontal, vertical), sample_features)


@dataclass
class Batch:
    """Clips as tensors: buffers name -> (B, T, C, h, w), reference (B, T, 3, h, w)."""

    buffers: dict[str, torch.Tensor]
    reference: torch.Tensor


class ClipSampler:
    """Draws batches of clips (same crop / augmentation / brightness for every frame of a clip).

    Clip length is min(frames, shortest sequence); crop size is min(crop, smallest frame
    side) rounded down to `multiple` (the model's pad_multiple). `flips`: random horizontal
    and vertical flips; `rotations`: a random number of quarter turns; `permute`: a random
    permutation of the colour channels (models/augment.py); `exposure`: "none" or "auto" (the
    module docstring). All randomness comes from `rng` (a numpy Generator), so a saved
    `rng.bit_generator.state` resumes the stream; an option that is off draws nothing, so the
    stream of a run without the newer options is the one it always was.
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
        rotations: bool = False,
        permute: bool = False,
        exposure: str = "none",
    ) -> None:
        if not sequences:
            raise InputError("no training sequences given")
        if exposure not in EXPOSURES:
            raise InputError(f"exposure must be one of {', '.join(EXPOSURES)}, got {exposure!r}")
        self.sequences = list(sequences)
        self.rng = rng
        self.batch = int(batch)
        self.flips = flips
        self.rotations = rotations
        self.permute = permute
        self.exposure = exposure
        self.brightness = (float(brightness[0]), float(brightness[1]))
        self.sample_features = tuple(sample_features)
        self.sample_counts = tuple(int(s) for s in sample_counts)
        if any(s < 1 for s in self.sample_counts):
            raise InputError(f"sample counts must be >= 1, got {list(self.sample_counts)}")
        self.frames = max(1, min(int(frames), min(s.frames for s in self.sequences)))
        # clips never cross a camera cut: sequences with no such clip are left out
        starts = [s.clip_starts(self.frames) for s in self.sequences]
        kept = [(s, st) for s, st in zip(self.sequences, starts, strict=True) if st]
        if not kept:
            raise InputError(
                f"every sequence has a camera cut inside every {self.frames}-frame clip"
            )
        self.sequences, self._starts = [s for s, _ in kept], [st for _, st in kept]
        side = min(int(crop), *(min(s.size) for s in self.sequences))
        self.crop = side - side % multiple
        if self.crop < multiple or self.crop < 1:
            raise InputError(
                f"frames of {min(min(s.size) for s in self.sequences)} px are too small for "
                f"crops that are multiples of {multiple}"
            )

    def clip(
        self, rng: np.random.Generator | None = None
    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """One clip: buffers name -> (T, C, crop, crop), reference (T, 3, crop, crop), drawn
        from `rng` (default: the sampler's own)."""
        rng = self.rng if rng is None else rng
        k = int(rng.integers(len(self.sequences)))
        seq, starts = self.sequences[k], self._starts[k]
        t0 = starts[int(rng.integers(len(starts)))]  # = the old draw where there is no cut
        h, w = seq.size
        y0 = int(rng.integers(h - self.crop + 1))
        x0 = int(rng.integers(w - self.crop + 1))
        flip_h = flip_v = False
        if self.flips:
            flip_h, flip_v = (bool(b) for b in rng.integers(2, size=2))
        scale = float(rng.uniform(*self.brightness))
        turns = int(rng.integers(4)) if self.rotations else 0
        perm = permutations()[int(rng.integers(6))] if self.permute else (0, 1, 2)
        window = (
            slice(t0, t0 + self.frames),
            Ellipsis,
            slice(y0, y0 + self.crop),
            slice(x0, x0 + self.crop),
        )
        # views of the crop (a memory-mapped sequence pages in only these rows), then one
        # owned float32 copy each: the transform's, or a plain one
        buffers = {n: a[window] for n, a in seq.buffers.items()}
        reference = seq.reference[window]
        transform = Transform(flip_h, flip_v, turns, perm)
        if transform.identity:
            buffers = {n: np.array(a, dtype=np.float32) for n, a in buffers.items()}
            reference = np.array(reference, dtype=np.float32)
        else:
            buffers, reference = apply_transform(
                buffers, reference, transform, self.sample_features
            )
        if self.exposure == "auto":
            scale *= self._exposure(buffers)
        if scale != 1.0:
            for name, arr in buffers.items():
                self._brighten(name, arr, scale)
            reference *= np.float32(scale)
        return buffers, reference

    def _exposure(self, buffers: dict[str, np.ndarray]) -> float:
        """Auto-exposure of the clip's noisy colour (the samples' mean radiance for a model
        that reads only `samples`)."""
        if "color" in buffers:
            color = buffers["color"]
        elif SAMPLES in buffers:
            color = buffers[SAMPLES][:, :, radiance_channels(self.sample_features)[:3]].mean(1)
        else:
            raise InputError("exposure 'auto' needs the color buffer among the model's inputs")
        return float(autoexposure(torch.from_numpy(np.ascontiguousarray(color))[None])[0])

    def _brighten(self, name: str, arr: np.ndarray, scale: float) -> None:
        """Scale the radiance of one buffer of a clip in place (its own float32 copy)."""
        if name in RADIANCE_BUFFERS:
            arr *= np.float32(scale)
        elif name == SAMPLES:
            arr[:, :, radiance_channels(self.sample_features)] *= np.float32(scale)

    def _subsample(self, clips: list, rng: np.random.Generator) -> None:
        """Give every clip the same number of samples (in place): a count drawn from
        sample_counts, or fewer if a clip has fewer (without sample_counts: the fewest any clip
        has); a random subset of each clip's samples."""
        if SAMPLES not in clips[0][0]:
            return
        have = [c[0][SAMPLES].shape[1] for c in clips]
        wanted = max(have)
        if self.sample_counts:
            wanted = self.sample_counts[int(rng.integers(len(self.sample_counts)))]
        count = min(wanted, *have)
        for (buffers, _), s in zip(clips, have, strict=True):
            if s != count:
                keep = np.sort(rng.choice(s, size=count, replace=False))
                buffers[SAMPLES] = np.ascontiguousarray(buffers[SAMPLES][:, keep])

    def sample(self, rng: np.random.Generator | None = None) -> Batch:
        """A batch of `batch` clips as float32 tensors, drawn from `rng` (default: the
        sampler's own)."""
        rng = self.rng if rng is None else rng
        clips = [self.clip(rng) for _ in range(self.batch)]
        self._subsample(clips, rng)
        names = clips[0][0].keys()
        return Batch(
            buffers={
                n: torch.from_numpy(np.ascontiguousarray(np.stack([c[0][n] for c in clips])))
                for n in names
            },
            reference=torch.from_numpy(np.ascontiguousarray(np.stack([c[1] for c in clips]))),
        )
