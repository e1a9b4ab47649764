"""WSKP: real-time Monte Carlo denoising with a weight sharing kernel prediction network (Fan21).

`WSKP.forward` reads like Fan21's pipeline (1-spp BMFR configuration, supplement s.1.1):

1. demodulate: irradiance r = color / (albedo + albedo_eps);
2. temporal accumulation of r (Fan21 accumulates like BMFR / SVGF): `models.temporal`
   reprojects the previous accumulation with the motion vectors, rejects it on depth /
   normal disagreement or off-screen, and blends (same scheme and state as AFN);
3. network input, 10 channels: (r_TA * (albedo + eps))^(1/2.2) (3), albedo (3),
   normal (3, as (n + 1) / 2), depth (1, scaled to [0, 1] per frame like AFN);
4. ImportanceNet: `layers` RepVGG blocks (5 x 5 + 3 x 3 + 1 x 1 branches, identity where
   in == out), LeakyReLU 0.1 between blocks, no BN, no bias; the last block outputs
   2 S channels (S = number of box sizes): S importance logits and S fusion logits;
5. weight sharing kernels: importance w_i = exp(clamp(logit_i)); filtered_i =
   boxsum_{s_i}(w_i r_TA) / boxsum_{s_i}(w_i) for box sizes s_i = 3, 5, ..., 13
   (`ops.weight_sharing_filter`);
6. kernel fusion: softmax over the S fusion logits per pixel, weighted sum of the S filtered
   images (`ops.kernel_fusion`);
7. remodulate: output = fused * (albedo + albedo_eps).

Steps 1-2 are the shared opening `models.accumulation.demodulate_and_accumulate`. At export
every RepVGG block folds into one 5 x 5 conv (`models.repvgg`, Fan21 s.1.1), by
the generic `export.deploy.to_deploy` pass.

Choices the paper leaves open (all in `WSKPConfig`, stored in checkpoints):
- albedo_eps = 1e-2 in demodulation and remodulation (as AFN; exactly invertible).
- TA: `models.temporal.TemporalConfig` (relative depth tolerance 0.1, normal dot > 0.9,
  min_alpha 0.2); state `ta` (r_TA and history length) and `geometry` (normal, depth).
- The network sees the accumulated colour r_TA * (albedo + eps), gamma-compressed with
  exponent 1 / `gamma` (2.2); the filter runs on HDR r_TA (no gamma). Fan21's official code
  also clips it to [0, 1] first (`clamp(x, 0, 1) ** 0.4545`): `input_clip` = True (the paper
  recipe, `denoise-train --recipe paper`); off by default, as the demo was trained.
- Loss: SMAPE (eps `smape_eps`, 1e-3 as Lee24's; the official code's is 1e-2, the paper
  recipe's) + temporal_weight x temporal SMAPE (0 in the paper recipe, as in Fan21).
- Block layout: the first block maps 10 -> width (no identity), blocks 2 .. layers - 1 are
  width -> width with identity, the last maps width -> 2 S (no identity) with no
  activation after it. Width 14, 6 layers (Fan21 "Ours (6-layer)"). `layers` = 3 is the
  size Lee24 timed as its WSKPN baseline (6.58 ms per 720p frame, Lee24 Table 10):
  10 -> 14 -> 14 -> 12. The shipped demo:wskp is this size: trained the same way it scored
  27.28 dB on the committed sequences against 26.84 dB for 6 layers.
- Cost once folded (5 x 5 convs, no biases; FLOP = 2 x multiply-adds, `benchmarks/flops.py`):
  25 x (10 x 14 + (layers - 2) x 14 x 14 + 14 x 12) multiply-adds per pixel: 6 layers 27.3 k,
  50.3 GFLOP per 1280 x 720 frame; 3 layers 12.6 k, 23.2 GFLOP.
- The activation sits outside the RepVGG block (the folded conv equals the branch sum).
- `logit_clamp` = 20: importance logits are clamped to [-20, 20] before exp, so the weights
  stay within exp(+-20) ~ 2e-9 .. 5e8: a weight sum is never 0 nor infinite in float32
  (13 x 13 boxes of irradiance up to ~1e27), and the fast kernel (no running sums) stays
  accurate over that range. Gradients stop where a logit is clamped.
- `bn`, `bias`: off by default (Fan21); available for experiments and tests. With bn the
  block uses batch statistics in training mode and running statistics in eval mode, which
  is what the folded conv reproduces.
- No pooling: `pad_multiple` = 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from rtdenoise.ops.weight_sharing_filter import FAN21_SIZES, sizes_to_attrs

from ..accumulation import (
    ACCUMULATION_INPUTS,
    ACCUMULATION_NOTE,
    ACCUMULATION_STATE,
    AccumulatingConfig,
    demodulate_and_accumulate,
)
from ..base import DenoiserModel, register_family
from ..features import depth01
from ..losses import sequence_loss
from ..ops.kernel_fusion import kernel_fusion
from ..ops.weight_sharing_filter import weight_sharing_filter
from ..repvgg import RepVGGBlock

INPUT_CHANNELS = 10  # (r_TA x albedo)^(1/2.2), albedo, normal, depth


@dataclass(frozen=True)
class WSKPConfig(AccumulatingConfig):
    """Sizes and constants of the WSKP model (see the module docstring)."""

    family = "wskp"

    width: int = 14
    layers: int = 6
    kernel_sizes: tuple[int, ...] = (5, 3, 1)
    sizes: tuple[int, ...] = FAN21_SIZES
    negative_slope: float = 0.1
    bn: bool = False
    bias: bool = False
    gamma: float = 2.2
    logit_clamp: float = 20.0
    depth_scale: str = "log"  # "log" or "linear"
    input_clip: bool = False  # Fan21 official: clamp(x, 0, 1) before the gamma
    smape_eps: float = 1e-3  # Fan21 official: 1e-2

    def validate(self) -> None:
        super().validate()  # AccumulatingConfig: the reprojection
        if self.width < 1:
            raise self.fail(f"width must be >= 1, got {self.width}")
        if self.layers < 2:
            raise self.fail(f"layers must be >= 2, got {self.layers}")
        if not self.kernel_sizes or any(k < 1 or k % 2 == 0 for k in self.kernel_sizes):
            raise self.fail(f"kernel_sizes must be odd and >= 1, got {self.kernel_sizes}")
        sizes_to_attrs(self.sizes)  # odd, evenly spaced (ValueError otherwise)
        if self.logit_clamp <= 0:
            raise self.fail(f"logit_clamp must be > 0, got {self.logit_clamp}")
        if self.gamma <= 0:
            raise self.fail(f"gamma must be > 0, got {self.gamma}")
        if self.smape_eps <= 0:
            raise self.fail(f"smape_eps must be > 0, got {self.smape_eps}")
        if self.depth_scale not in ("log", "linear"):
            raise self.fail(f"depth_scale must be 'log' or 'linear', got {self.depth_scale!r}")


class ImportanceNet(nn.Module):
    """Fan21 ImportanceNet (1-spp configuration): RepVGG blocks, LeakyReLU between them."""

    def __init__(self, in_channels: int, out_channels: int, config: WSKPConfig) -> None:
        super().__init__()
        widths = [in_channels] + [config.width] * (config.layers - 1) + [out_channels]
        # identity only where in == out (Fan21 s.1.1), i.e. the width -> width blocks
        self.blocks = nn.ModuleList(
            RepVGGBlock(c_in, c_out, config.kernel_sizes, bn=config.bn, bias=config.bias)
            for c_in, c_out in zip(widths[:-1], widths[1:], strict=True)
        )
        self.negative_slope = config.negative_slope

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for block in self.blocks[:-1]:
            x = F.leaky_relu(block(x), self.negative_slope)
        return self.blocks[-1](x)


@register_family
class WSKP(DenoiserModel):
    """Fan21 weight sharing kernel prediction with temporal accumulation (module docstring)."""

    family = "wskp"
    config_class = WSKPConfig
    example_config = {"width": 8}
    inputs = ACCUMULATION_INPUTS
    state_specs = ACCUMULATION_STATE
    pad_multiple = 1
    input_note = ACCUMULATION_NOTE

    def __init__(self, config: WSKPConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = WSKPConfig.of(config)
        self.importance_net = ImportanceNet(INPUT_CHANNELS, 2 * len(config.sizes), config)

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        # 1-2. Demodulation and temporal accumulation of the irradiance.
        frame = demodulate_and_accumulate(buffers, state, reset, self.cfg)
        r_ta = frame.accumulated

        # 3. Network input (10 ch): gamma-compressed accumulated colour and the features.
        colour = r_ta * frame.modulation
        top = 1.0 if self.cfg.input_clip else None  # Fan21 official code: clamp(x, 0, 1)
        colour = torch.clamp(colour, min=0.0, max=top)
        radiance = torch.pow(colour, 1.0 / self.cfg.gamma)
        normal01 = 0.5 * (frame.normal + 1.0)
        depth_01 = depth01(frame.depth, self.cfg.depth_scale)
        net_in = torch.cat((radiance, frame.albedo, normal01, depth_01), dim=1)

        # 4. ImportanceNet: S importance logits and S fusion logits.
        s = len(self.cfg.sizes)
        logits = self.importance_net(net_in)
        clamp = self.cfg.logit_clamp
        importance = torch.exp(torch.clamp(logits[:, :s], -clamp, clamp))

        # 5. Weight sharing kernels of sizes 3 .. 13 on the HDR accumulated irradiance.
        filtered = weight_sharing_filter(r_ta, importance, self.cfg.sizes)

        # 6. Kernel fusion (softmax over the S sizes per pixel).
        fused = kernel_fusion(filtered, logits[:, s:])

        # 7. Remodulation.
        return fused * frame.modulation, frame.state

    def loss(
        self, outputs: torch.Tensor, reference: torch.Tensor, temporal_weight: float
    ) -> torch.Tensor:
        """SMAPE with eps `smape_eps` + temporal_weight x temporal SMAPE (Fan21's official loss
        is the SMAPE alone, eps 1e-2: the paper recipe)."""
        return sequence_loss(outputs, reference, temporal_weight, eps=self.cfg.smape_eps)


__all__ = ["INPUT_CHANNELS", "WSKP", "ImportanceNet", "WSKPConfig"]
