"""The input guard: what may enter a model, and through it the temporal history.

`Denoiser.process` passes every buffer of every frame through `guard_buffer` before the graph
runs, so the rule holds for every model, exported before or after this module existed. The
contract (docs/contract.md, "Buffers") says what each buffer holds; a value that cannot be that
is replaced or clamped here, in a copy (never the caller's array), and counted in pixels per
buffer. docs/reliability.md has the table of every case. C and C++ hosts get the same rules
from the C++ library (bridge/native_ops/guard.cpp, rtdenoise_guard.h), bit for bit
(tests/test_native_guard.py): a change here is made there too.

`RULES`, per buffer: the range [low, high] and what NaN / +Inf / -Inf become.

| buffer | range | NaN | +Inf | -Inf | above the range |
|---|---|---|---|---|---|
| color, color_b | [0, 65504] | 0 | 0 | 0 | 0 |
| albedo | [0, 1] | 0 | 0 | 0 | clamped |
| normal | [-1, 1] | 0 | 0 | 0 | clamped |
| depth | [0, 1e10] | 0 | 1e10 | 0 | clamped |
| motion | [-2 max(H, W), 2 max(H, W)] px | +bound | +bound | -bound | clamped |
| anything else (samples) | [-65504, 65504] | 0 | 0 | 0 | clamped |

Values below the range are clamped. 65504 is the largest half float: a real-time renderer's
HDR target holds no more, nor does the half-float EXR `denoise-run` writes, and a model run in
float16 would overflow above it; radiance above it is what half floats call Inf, and is
treated as such (0), because a region clamped to 65504 would stay in the history for some 50
frames while a black one is gone in one (measured with demo:afn, docs/reliability.md).
Pre-expose physically scaled renders into that range. Motion beyond 2 max(H, W) points
off-screen either way; NaN motion is made off-screen, so the pixel's history is rejected
rather than trusted.

Outliers (`color`, `color_b`): a pixel whose largest channel exceeds `OUTLIER_RATIO` times the
largest channel among its 8 neighbours (taken as at least `OUTLIER_FLOOR`) is scaled down to
that neighbour maximum. Normal Monte Carlo fireflies stay (the model's job; on the committed
1-spp sequences the largest pixel reaches 10 % of this threshold); a 1e4 sample among values
near 1 is gone before it can enter the history. Two adjacent outliers shield each other: they
are only range-checked.

Unusable guides: a guide buffer (albedo, normal, depth) that is zero everywhere is a missing
render pass; the demodulated irradiance colour / (albedo + eps) of a zero albedo is up to 100
times too bright for the next frame's history. `Denoiser` runs such a frame as the first of a
new history and starts another one after it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .contract import HALF_MAX

ALBEDO_MAX = 1.0
DEPTH_MAX = 1e10
MOTION_FRAMES = 2.0  # motion bound in multiples of max(H, W)
OUTLIER_RATIO = 64.0
OUTLIER_FLOOR = 16.0
GUIDES = ("albedo", "normal", "depth")


@dataclass(frozen=True)
class Rule:
    """Range of one buffer and what NaN / +Inf / -Inf become. `frame_relative`: the five
    numbers are multiples of max(H, W)."""

    low: float
    high: float
    nan: float = 0.0
    posinf: float = 0.0
    neginf: float = 0.0
    above: float | None = None  # what values above `high` become (None: `high`)
    outliers: bool = False
    frame_relative: bool = False

    def scaled(self, hw: tuple[int, ...]) -> Rule:
        """The rule in absolute values for a frame of size `hw`."""
        if not self.frame_relative:
            return self
        s = float(max(hw))
        return Rule(
            self.low * s, self.high * s, self.nan * s, self.posinf * s, self.neginf * s,
            None if self.above is None else self.above * s, self.outliers,
        )  # fmt: skip


RULES: dict[str, Rule] = {
    "color": Rule(0.0, HALF_MAX, above=0.0, outliers=True),
    "color_b": Rule(0.0, HALF_MAX, above=0.0, outliers=True),
    "albedo": Rule(0.0, ALBEDO_MAX),
    "normal": Rule(-1.0, 1.0),
    "depth": Rule(0.0, DEPTH_MAX, posinf=DEPTH_MAX),
    "motion": Rule(
        -MOTION_FRAMES,
        MOTION_FRAMES,
        MOTION_FRAMES,
        MOTION_FRAMES,
        -MOTION_FRAMES,
        frame_relative=True,
    ),  # fmt: skip
}
DEFAULT_RULE = Rule(-HALF_MAX, HALF_MAX)


def rule_for(name: str, hw: tuple[int, ...]) -> Rule:
    """The absolute rule of buffer `name` for a frame of size `hw` = (H, W)."""
    return RULES.get(name, DEFAULT_RULE).scaled(hw)


@dataclass
class Guarded:
    """One buffer after the guard."""

    array: np.ndarray  # the input itself when nothing was changed, else a fixed copy
    nonfinite: np.ndarray | None = None  # (H, W) mask of pixels that had NaN/Inf
    clamped: int = 0  # pixels with a value outside the range (clamped)
    outliers: int = 0  # isolated outlier pixels scaled down
    zero: bool = False  # every value is 0 (after the fixes)


def _pixel_mask(mask: np.ndarray) -> np.ndarray:
    """(H, W): True where any value of the (..., H, W) mask is."""
    h, w = mask.shape[-2:]
    return mask.reshape(-1, h, w).any(axis=0)


def _surely_finite(a: np.ndarray) -> bool:
    """True when every value of the float array `a` is finite, by one cheap pass (a sum); False
    means "look closer" (a finite sum may overflow)."""
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(a.sum()))


def nonfinite_pixels(a: np.ndarray) -> np.ndarray | None:
    """The (H, W) mask of the pixels of a (..., H, W) float array with NaN/Inf in any channel,
    or None when every value is finite: then it costs one pass (a sum), the common case."""
    if _surely_finite(a):
        return None
    bad = ~np.isfinite(a)
    return _pixel_mask(bad) if bad.any() else None


def count_nonfinite(a: np.ndarray) -> int:
    """Number of NaN/Inf values of `a` (0 for an integer array); one sum when there are none."""
    if a.dtype.kind != "f" or _surely_finite(a):
        return 0
    return int(a.size - np.count_nonzero(np.isfinite(a)))


def replace_nonfinite(name: str, a: np.ndarray) -> np.ndarray | None:
    """Replace NaN/Inf in `a` (..., H, W) in place by the buffer's rule; the (H, W) mask of the
    pixels that had any, or None when every value is finite (one cheap pass: a sum)."""
    mask = nonfinite_pixels(a)
    if mask is None:
        return None
    r = rule_for(name, a.shape[-2:])
    np.nan_to_num(a, copy=False, nan=r.nan, posinf=r.posinf, neginf=r.neginf)
    return mask


def _neighbour_max(m: np.ndarray, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Largest value of `m` (H, W), >= 0, among the 8 neighbours of each (ys, xs)."""
    h, w = m.shape
    best = np.zeros(len(ys), np.float32)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == dx == 0:
                continue
            yy, xx = ys + dy, xs + dx
            inside = (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
            values = m[np.clip(yy, 0, h - 1), np.clip(xx, 0, w - 1)]
            np.maximum(best, np.where(inside, values, 0.0), out=best)
    return best


def replace_outliers(a: np.ndarray) -> int:
    """Scale isolated outlier pixels of `a` (..., C, H, W), values >= 0, down to their
    neighbour maximum, in place; returns how many there were."""
    h, w = a.shape[-2:]
    m = a.reshape(-1, h, w).max(axis=0)
    ys, xs = np.nonzero(m > OUTLIER_RATIO * OUTLIER_FLOOR)  # no pixel below can be one
    if not len(ys):
        return 0
    peak = m[ys, xs]
    near = _neighbour_max(m, ys, xs)
    hit = peak > OUTLIER_RATIO * np.maximum(near, OUTLIER_FLOOR)
    if not hit.any():
        return 0
    ys, xs = ys[hit], xs[hit]
    a[..., ys, xs] *= (near[hit] / peak[hit]).astype(np.float32)
    return int(hit.sum())


def guard_buffer(name: str, a: np.ndarray, *, owned: bool = False) -> Guarded:
    """Apply buffer `name`'s rule to the float32 array `a` (..., H, W).

    owned: `a` may be changed in place (else it is copied first, and only when something
    needs fixing). Costs two passes (min, max) when nothing does.
    """
    r = rule_for(name, a.shape[-2:])
    with np.errstate(invalid="ignore"):
        lo, hi = float(a.min()), float(a.max())  # NaN if any value is NaN
    finite = np.isfinite(lo) and np.isfinite(hi)
    in_range = finite and r.low <= lo and hi <= r.high
    if in_range and not (r.outliers and hi > OUTLIER_RATIO * OUTLIER_FLOOR):
        return Guarded(a, zero=lo == 0.0 and hi == 0.0)
    if not owned:
        a = a.copy()
    out = Guarded(a)
    if not finite:
        out.nonfinite = replace_nonfinite(name, a)
    if not in_range:
        above = a > r.high
        outside = above | (a < r.low)
        out.clamped = int(_pixel_mask(outside).sum())
        if r.above is not None:
            a[above] = r.above
        np.clip(a, r.low, r.high, out=a)
    if r.outliers:
        out.outliers = replace_outliers(a)
    out.zero = not a.any()
    return out


@dataclass
class GuardReport:
    """What the guard did to one frame, and why the frame started a new history."""

    nonfinite: dict[str, int] = field(default_factory=dict)  # pixels with NaN/Inf, per buffer
    clamped: dict[str, int] = field(default_factory=dict)  # pixels out of range, per buffer
    outliers: dict[str, int] = field(default_factory=dict)  # outlier pixels, per buffer
    unusable: tuple[str, ...] = ()  # guide buffers that were zero everywhere
    nonfinite_pixels: int = 0  # pixels with NaN/Inf in any buffer
    output_nonfinite: int = 0  # output pixels that came out NaN/Inf (replaced by 0)
    reset: str | None = None  # why this frame started a new history (None: it continued one)

    @property
    def changed(self) -> bool:
        """True when the guard changed the input or the output of this frame."""
        return bool(self.nonfinite or self.clamped or self.outliers or self.unusable) or bool(
            self.output_nonfinite
        )

    def summary(self) -> str:
        """One line: what was fixed (empty when nothing was)."""
        parts = []
        if self.nonfinite:
            parts.append(f"{self.nonfinite_pixels} pixels with NaN/Inf in {_names(self.nonfinite)}")
        if self.clamped:
            parts.append(f"{sum(self.clamped.values())} out of range in {_names(self.clamped)}")
        if self.outliers:
            parts.append(f"{sum(self.outliers.values())} outliers in {_names(self.outliers)}")
        if self.unusable:
            parts.append(f"{', '.join(self.unusable)} zero everywhere (history restarted)")
        if self.output_nonfinite:
            parts.append(f"{self.output_nonfinite} NaN/Inf output pixels (history restarted)")
        return "; ".join(parts)


def _names(counts: dict[str, int]) -> str:
    return ", ".join(counts)


@dataclass
class GuardTotals:
    """Counts over every frame a `Denoiser` processed."""

    nonfinite_pixels: int = 0
    clamped: int = 0
    outliers: int = 0
    unusable_frames: int = 0
    output_nonfinite: int = 0
    resets: dict[str, int] = field(default_factory=dict)  # reason -> frames

    def add(self, report: GuardReport) -> None:
        self.nonfinite_pixels += report.nonfinite_pixels
        self.clamped += sum(report.clamped.values())
        self.outliers += sum(report.outliers.values())
        self.unusable_frames += bool(report.unusable)
        self.output_nonfinite += report.output_nonfinite
        if report.reset:
            key = report.reset.split(":")[0]
            self.resets[key] = self.resets.get(key, 0) + 1


def guard_buffers(
    arrays: dict[str, np.ndarray], owned: Sequence[str] = ()
) -> tuple[dict[str, np.ndarray], GuardReport]:
    """Guard every buffer of one frame (name -> (..., H, W) float32); the fixed arrays and
    the report. `owned`: names whose arrays may be changed in place."""
    report = GuardReport()
    fixed: dict[str, np.ndarray] = {}
    union: np.ndarray | None = None
    unusable = []
    for name, a in arrays.items():
        g = guard_buffer(name, a, owned=name in owned)
        fixed[name] = g.array
        if g.nonfinite is not None:
            report.nonfinite[name] = int(g.nonfinite.sum())
            union = g.nonfinite if union is None else union | g.nonfinite
        if g.clamped:
            report.clamped[name] = g.clamped
        if g.outliers:
            report.outliers[name] = g.outliers
        if g.zero and name in GUIDES:
            unusable.append(name)
    report.unusable = tuple(unusable)
    report.nonfinite_pixels = 0 if union is None else int(union.sum())
    return fixed, report


__all__ = [
    "ALBEDO_MAX",
    "DEPTH_MAX",
    "GUIDES",
    "HALF_MAX",
    "MOTION_FRAMES",
    "OUTLIER_FLOOR",
    "OUTLIER_RATIO",
    "RULES",
    "GuardReport",
    "GuardTotals",
    "Guarded",
    "Rule",
    "count_nonfinite",
    "guard_buffer",
    "guard_buffers",
    "nonfinite_pixels",
    "replace_nonfinite",
    "replace_outliers",
    "rule_for",
]
