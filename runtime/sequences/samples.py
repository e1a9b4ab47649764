"""Per-sample input: the contract's rank-5 `samples` buffer, (S, C, H, W), from EXR frames.

A model that reads `samples` names its per-sample features in its config, key
`sample_features`: canonical buffer names in order (docs/contract.md, "Buffers"), e.g.
("color", "albedo", "normal", "depth") -> C = 3 + 3 + 3 + 1 = 10 channels per sample; `color`
is the sample's own radiance.

EXR layout (canonical): sample i is a miniature canonical frame under the prefix `sample<i>.`:
`sample0.R/G/B` (its radiance), `sample0.albedo.R/G/B`, `sample0.normal.X/Y/Z`,
`sample0.depth.Z`, then `sample1.*`, ... (S = the number of consecutive `sample<i>.R` layers).
The frame's `R,G,B` stay the mean of its samples. A file without sample layers gives S = 1
from its pixel buffers: the pixel mean of the radiance and the pixel's features stand in
for one sample (`samples_from_buffers`).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..contract import BUFFER_CHANNELS, RADIANCE_BUFFERS, SCREEN_XY_BUFFERS
from ..errors import InputError
from .layouts import LAYOUTS

SAMPLE_FEATURES_KEY = "sample_features"
DEFAULT_SAMPLE_FEATURES = ("color", "albedo", "normal", "depth")
PREFIX = "sample"


def check_features(features: Sequence[str]) -> tuple[str, ...]:
    """`features` as a tuple; InputError unless they are distinct per-pixel canonical buffers."""
    features = tuple(features)
    bad = [f for f in features if f not in BUFFER_CHANNELS or f == "motion"]
    if not features or bad or len(set(features)) != len(features):
        raise InputError(
            f"sample features must be distinct canonical buffers other than motion "
            f"({', '.join(b for b in BUFFER_CHANNELS if b != 'motion')}), got {list(features)}"
        )
    return features


def sample_features_of(config: Mapping) -> tuple[str, ...]:
    """The per-sample features a model's config names (the default set if it names none)."""
    return check_features(config.get(SAMPLE_FEATURES_KEY, DEFAULT_SAMPLE_FEATURES))


def feature_channels(features: Sequence[str]) -> int:
    """C of the samples buffer: the channel count of the features, summed."""
    return sum(BUFFER_CHANNELS[f] for f in check_features(features))


def feature_offsets(features: Sequence[str]) -> dict[str, int]:
    """Feature -> its first channel in a sample."""
    offsets, c = {}, 0
    for f in check_features(features):
        offsets[f] = c
        c += BUFFER_CHANNELS[f]
    return offsets


def sample_layer(index: int, feature: str) -> str:
    """EXR layer of `feature` of sample `index` (`sample0` for colour, `sample0.albedo`, ...)."""
    layer = LAYOUTS["canonical"].layers[feature][0]
    return f"{PREFIX}{index}" + (f".{layer}" if layer else "")


def sample_channels(index: int, feature: str) -> list[str]:
    """Full EXR channel names of `feature` of sample `index`, in channel order (for writers)."""
    comps = {1: ("Z",), 2: ("X", "Y"), 3: ("X", "Y", "Z") if feature == "normal" else "RGB"}
    return [f"{sample_layer(index, feature)}.{c}" for c in comps[BUFFER_CHANNELS[feature]]]


def sample_count(channel_names: Sequence[str] | Mapping[str, object]) -> int:
    """S: how many consecutive samples (`sample0.R`, `sample1.R`, ...) a file holds."""
    names = set(channel_names)
    s = 0
    while f"{PREFIX}{s}.R" in names:
        s += 1
    return s


def read_samples(
    channels: Mapping[str, np.ndarray], features: Sequence[str], source: str = "<file>"
) -> np.ndarray | None:
    """(S, C, H, W) float32 from a file's sample layers, or None if it has none.

    InputError (naming the file and channel) when a sample lacks one of the features.
    """
    plan = plan_samples(channels.keys(), features, source)
    return plan.stack(channels) if plan.layers else None


def samples_from_buffers(buffers: Mapping[str, np.ndarray], features: Sequence[str]) -> np.ndarray:
    """(1, C, H, W): S = 1 from a frame's pixel buffers (the pixel mean as the one sample)."""
    features = check_features(features)
    missing = [f for f in features if f not in buffers]
    if missing:
        raise InputError(
            f"no sample layers and no pixel buffer {missing[0]!r} to make S = 1 samples from "
            f"(present: {sorted(buffers)})"
        )
    return np.concatenate([np.asarray(buffers[f], np.float32) for f in features])[None]


@dataclass(frozen=True)
class SamplePlan:
    """How a sequence's samples buffer is read: `layers` holds, per sample, the EXR channel
    names of its features in order; empty: S = 1 from the pixel buffers named `features`."""

    features: tuple[str, ...]
    layers: tuple[tuple[str, ...], ...] = ()

    @property
    def channel_names(self) -> list[str]:
        return [n for sample in self.layers for n in sample]

    def pixel_buffers(self) -> tuple[str, ...]:
        """The pixel buffers the samples are made from (none when the file has layers)."""
        return () if self.layers else self.features

    def stack(self, channels: Mapping[str, np.ndarray]) -> np.ndarray:
        """(S, C, H, W) float32 from the planned sample channels of one file."""
        return np.stack([np.stack([channels[n] for n in s], dtype=np.float32) for s in self.layers])


def plan_samples(
    channel_names: Collection[str], features: Sequence[str], source: str = "<file>"
) -> SamplePlan:
    """The SamplePlan of a file from its channel names; InputError naming the file and the
    channel when a sample lacks one of the features."""
    features = check_features(features)
    present = set(channel_names)
    layers = []
    for i in range(sample_count(present)):
        names = [n for f in features for n in sample_channels(i, f)]
        missing = [n for n in names if n not in present]
        if missing:
            raise InputError(
                f"{source}: sample {i} has no channel {', '.join(missing)} (per-sample features "
                f"{', '.join(features)})"
            )
        layers.append(tuple(names))
    return SamplePlan(features, tuple(layers))


def signed_channels(features: Sequence[str]) -> tuple[list[int], list[int]]:
    """Channels of a sample that change sign under a horizontal / vertical image flip (the x and
    y components of its screen-space features: the normal)."""
    off = feature_offsets(features)
    xy = [f for f in features if f in SCREEN_XY_BUFFERS]
    return [off[f] for f in xy], [off[f] + 1 for f in xy]


def radiance_channels(features: Sequence[str]) -> list[int]:
    """Channels of a sample that hold radiance (scaled by a brightness augmentation)."""
    off = feature_offsets(features)
    return [off[f] + c for f in features if f in RADIANCE_BUFFERS for c in range(3)]


__all__ = [
    "DEFAULT_SAMPLE_FEATURES",
    "SAMPLE_FEATURES_KEY",
    "check_features",
    "feature_channels",
    "feature_offsets",
    "radiance_channels",
    "SamplePlan",
    "plan_samples",
    "read_samples",
    "sample_channels",
    "sample_count",
    "sample_features_of",
    "sample_layer",
    "samples_from_buffers",
    "signed_channels",
]
