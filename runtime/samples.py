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

from collections.abc import Mapping, Sequence

import numpy as np

from .contract import BUFFER_CHANNELS
from .errors import InputError
from .layouts import LAYOUTS, Layout, extract_buffers

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


def _sample_layout(index: int, features: tuple[str, ...]) -> Layout:
    return Layout(
        name=f"{PREFIX}{index}",
        description=f"sample {index}",
        layers={f: (sample_layer(index, f),) for f in features},
        required=features,
    )


def read_samples(
    channels: Mapping[str, np.ndarray], features: Sequence[str], source: str = "<file>"
) -> np.ndarray | None:
    """(S, C, H, W) float32 from a file's sample layers, or None if it has none.

    InputError (naming the file and channel) when a sample lacks one of the features.
    """
    features = check_features(features)
    s = sample_count(channels)
    if s == 0:
        return None
    out = []
    for i in range(s):
        bufs = extract_buffers(channels, _sample_layout(i, features), source=source)
        out.append(np.concatenate([bufs[f] for f in features]))
    return np.stack(out).astype(np.float32, copy=False)


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


def signed_channels(features: Sequence[str]) -> tuple[list[int], list[int]]:
    """Channels of a sample that change sign under a horizontal / vertical image flip (the x and
    y components of the normal)."""
    off = feature_offsets(features)
    if "normal" not in off:
        return [], []
    return [off["normal"]], [off["normal"] + 1]


def radiance_channels(features: Sequence[str]) -> list[int]:
    """Channels of a sample that hold radiance (scaled by a brightness augmentation)."""
    off = feature_offsets(features)
    return [off[f] + c for f in ("color", "color_b") if f in off for c in range(3)]


__all__ = [
    "DEFAULT_SAMPLE_FEATURES",
    "SAMPLE_FEATURES_KEY",
    "check_features",
    "feature_channels",
    "feature_offsets",
    "radiance_channels",
    "read_samples",
    "sample_channels",
    "sample_count",
    "sample_features_of",
    "sample_layer",
    "samples_from_buffers",
    "signed_channels",
]
