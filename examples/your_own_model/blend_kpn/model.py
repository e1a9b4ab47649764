"""BlendKPN: temporal accumulation, then a small CNN predicts how much each pixel blends towards
its neighbours (two NeighbourBlend passes). Written against rtdenoise's public model API
(`rtdenoise.models`), installed with its own entry points."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from rtdenoise.models import (
    ACCUMULATION_INPUTS,
    ACCUMULATION_NOTE,
    ACCUMULATION_STATE,
    AccumulatingConfig,
    DenoiserModel,
    demodulate_and_accumulate,
    register_family,
)

from .op_torch import neighbour_blend


@dataclass(frozen=True)
class BlendKPNConfig(AccumulatingConfig):
    family = "blendkpn"
    width: int = 16
    passes: int = 2

    def validate(self) -> None:
        if self.width < 1 or self.passes < 1:
            raise self.fail(f"width and passes must be >= 1, got {self.width}, {self.passes}")


@register_family
class BlendKPN(DenoiserModel):
    family = "blendkpn"
    config_class = BlendKPNConfig
    example_config = {"width": 8}
    inputs = ACCUMULATION_INPUTS
    state_specs = ACCUMULATION_STATE
    input_note = ACCUMULATION_NOTE

    def __init__(self, config: BlendKPNConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = BlendKPNConfig.of(config)
        w = config.width
        self.net = nn.Sequential(
            nn.Conv2d(9, w, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(w, w, 3, padding=1),
            nn.ReLU(),
            nn.Conv2d(w, config.passes, 3, padding=1),
        )

    def forward(self, buffers, state, reset):
        # 1. Demodulation and temporal accumulation (rtdenoise's shared opening).
        frame = demodulate_and_accumulate(buffers, state, reset, self.cfg)
        # 2. Per-pixel blend weights from the accumulated irradiance and the features.
        x = torch.cat((torch.log1p(frame.accumulated), frame.albedo, frame.normal), dim=1)
        weights = torch.sigmoid(self.net(x))
        # 3. The filter: NeighbourBlend passes, then remodulation.
        out = frame.accumulated
        for k in range(self.cfg.passes):
            out = neighbour_blend(out, weights[:, k : k + 1])
        return out * frame.modulation, frame.state
