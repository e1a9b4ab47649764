"""The shared opening of the accumulating families (AFN, WSKP): demodulate, then accumulate.

    irradiance = color / (albedo + albedo_eps)            (Lee24 III-A, after Chaitanya17)
    accumulated, blend = TA(irradiance, history)          (models.temporal)

`demodulate_and_accumulate` is the one function those models call first; `AccumulatingConfig`
holds its constants (every field in the checkpoint config), `ACCUMULATION_STATE` the state it
keeps: `ta` (accumulated irradiance and history length) and `geometry` (normal and depth of the
last frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .base import FamilyConfig, StateSpec
from .features import frame_inputs
from .ops.temporal_accumulation import temporal_accumulation
from .temporal import TemporalConfig

# AccumulatingConfig.reprojection -> the op's per_tap attribute (models.temporal)
REPROJECTIONS = {"bilinear": 0, "per_tap": 1, "per_tap_hdr": 2, "per_tap_hdr2": 3}
ACCUMULATION_INPUTS = ("color", "albedo", "normal", "depth", "motion")
ACCUMULATION_STATE = (StateSpec("ta", 4, 1), StateSpec("geometry", 4, 1))
ACCUMULATION_NOTE = (
    "pass linear HDR radiance (color), albedo, normal in [-1, 1], linear view depth and "
    "motion in pixels (previous = current + motion); do NOT demodulate, tonemap, "
    "accumulate or normalise: the graph does it"
)


@dataclass(frozen=True)
class AccumulatingConfig(FamilyConfig):
    """Demodulation and temporal-accumulation constants (models.temporal.TemporalConfig)."""

    albedo_eps: float = 1e-2  # demodulation and remodulation (exactly invertible)
    depth_tolerance: float = 0.1
    normal_threshold: float = 0.9
    min_alpha: float = 0.2
    max_history: float = 64.0
    # TA's reprojection (models.temporal): "bilinear" tests the warped geometry once per
    # pixel (a checkpoint saved before this field); "per_tap" tests each bilinear tap and
    # renormalises over the accepted ones (SVGF, BMFR); "per_tap_hdr" also weighs down a tap
    # brighter than 4x the darkest accepted one + 1 by its excess (after Karis14), so a small
    # bright light does not bleed into its dark neighbours through the history;
    # "per_tap_hdr2" divides by the square of 1 + the excess (a light's trail falls as 1 / its
    # brightness instead of staying about one unit).
    reprojection: str = "bilinear"

    def temporal(self) -> TemporalConfig:
        return TemporalConfig(
            depth_tolerance=self.depth_tolerance,
            normal_threshold=self.normal_threshold,
            min_alpha=self.min_alpha,
            max_history=self.max_history,
            per_tap=REPROJECTIONS[self.reprojection],
        )

    def validate(self) -> None:
        """The accumulation's own fields (the families' `validate` calls it first)."""
        if self.reprojection not in REPROJECTIONS:
            raise self.fail(
                f"reprojection must be one of {', '.join(map(repr, REPROJECTIONS))}, "
                f"got {self.reprojection!r}"
            )


@dataclass
class Accumulated:
    """One frame after the opening: sanitised buffers, demodulated and accumulated radiance."""

    color: torch.Tensor
    albedo: torch.Tensor
    normal: torch.Tensor
    depth: torch.Tensor
    motion: torch.Tensor
    modulation: torch.Tensor  # albedo + albedo_eps: remodulate the output with it
    irradiance: torch.Tensor  # this frame's color / modulation
    accumulated: torch.Tensor  # r_TA
    blend: torch.Tensor  # the TA blend weight a (1 on fresh pixels)
    state: dict[str, torch.Tensor]  # next `ta` and `geometry`


def demodulate_and_accumulate(
    buffers: dict[str, torch.Tensor],
    state: dict[str, torch.Tensor],
    reset: torch.Tensor,
    config: AccumulatingConfig,
) -> Accumulated:
    """Demodulate the frame by its albedo and accumulate it with the reprojected history."""
    color, albedo, normal, depth, motion = frame_inputs(buffers)
    modulation = albedo + config.albedo_eps
    irradiance = color / modulation
    accumulated, blend, next_ta, next_geometry = temporal_accumulation(
        irradiance, motion, depth, normal, state["ta"], state["geometry"], reset, config.temporal()
    )
    return Accumulated(
        color=color,
        albedo=albedo,
        normal=normal,
        depth=depth,
        motion=motion,
        modulation=modulation,
        irradiance=irradiance,
        accumulated=accumulated,
        blend=blend,
        state={"ta": next_ta, "geometry": next_geometry},
    )
