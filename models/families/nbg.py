"""NBG: real-time Monte Carlo denoising with the neural bilateral grid (Meng20).

`NBG.forward` reads like Meng20 Fig. 1 with the 2-layer GuideNet of Fig. 2 (left), the 1-spp
configuration:

0. (optional, off by default) outlier suppression of the noisy radiance (Meng20 s.5, after
   KBS15 / LBF15 as in the official `outlier_lib`): a pixel whose tonemapped luminance lies
   more than `outlier_sigma` standard deviations from that of its similar 3 x 3 neighbours is
   replaced by their mean radiance;
1. albedo demodulation (s.4.1 "Data decomposition"): irradiance r = color / (albedo + eps);
2. temporal accumulation of r with history weight 0.8 (s.4.6: "decay factor of the previous
   frame 0.2"): `models.accumulation.demodulate_and_accumulate` with min_alpha = 0.2;
3. GuideNet input (s.5, 10 channels): S(r_TA * (albedo + eps)), albedo, normal as (n + 1) / 2,
   depth scaled to [0, 1] per frame, where S(x) = clip(max(x, 0)^(1 / 2.2), 0, 1) (the official
   `tone_mapping`; `guide_tonemap` = "log1p" reads log1p(r_TA * (albedo + eps)) instead);
4. GuideNet (Fig. 2 left): 5 x 5 conv 10 -> 20, leaky ReLU, 5 x 5 conv 20 -> 5, sigmoid:
   three guides g_k = 255 sigma_k and weights w1, w2 (s.4.1, s.4.5);
5. three bilateral grids (s.4.2-4.5), (s, D) = (4, 64), (8, 32), (16, 16): R_k =
   BilateralGrid(r_TA, g_k) (`ops.bilateral_grid`: splat eqs. (10)-(12), slice eq. (13)) on
   the HDR accumulated irradiance;
6. composition (eq. (15)): R = w1 R_1 + w2 R_2 + (1 - w1 - w2) R_3;
7. remodulation (s.4.3 "Post-processing"): output = max(R, 0) * (albedo + eps).

Training loss `NBG.loss`: eq. (14), L1 between S(output) and S(reference).

Choices the paper leaves open (all in `NBGConfig`, stored in checkpoints):
- albedo_eps = 1e-2 in demodulation and remodulation (as AFN / WSKP; exactly invertible).
- TA: `models.temporal` (relative depth tolerance 0.1, normal dot > 0.9, weight
  max(0.2, 1 / (history + 1)): uniform average over the first frames, then the 0.8 / 0.2
  moving average); state `ta` and `geometry`.
- GuideNet activation: leaky ReLU with slope `negative_slope` = 0.2 (the official code's lrelu;
  the paper's text says ReLU: slope 0). Zero ("SAME") padding as the official conv layers
  (`padding` "zeros"), or "replicate": the edge pixel repeated, as afn's and affinity's key.
- `edge_margin` (0): pixels of the frame's edge repeated on every side before the network and
  cropped from its output (`DenoiserModel.edge_margin`, contract key `rtdenoise.edge_margin`):
  weights that smear a light at the frame's edge into the first columns keep it in place when
  the edge lies `edge_margin` pixels inside what they see.
- `pointwise_guide` (off in Meng20): a 1 x 1 conv from GuideNet's input added to its last
  conv's output before the sigmoid, the pointwise guidance map of HDRNet (Gharbi17): GuideNet's
  k x k convs give a dark pixel beside a light nearly the light's guide, so the light's grid cell
  reaches it; a per-pixel path lets the guides part at that pixel.
- `history_gate` (off in Meng20): GuideNet reads S(color) of this frame as 3 more channels
  and outputs one more, a gate b in (0, 1); the grids filter r + b (r_TA - r), r this frame's
  irradiance, instead of r_TA (the TA state is unchanged). TA's tests are geometric: on
  reflections and through glass the motion vectors follow the surface, not the image, and the
  accumulated history trails; the gate lets the network fall back to the frame. Its initial
  logit is GATE_BIAS (b = 0.98).
- `history_input` (off in Meng20; afn's key): GuideNet reads TA's current-frame weight a as one
  more channel, the last (1 on pixels without history, 0.2 once converged): a frame after a
  reset or a disocclusion is 1 spp, and its best guides are not those of an accumulated one.
- Initialisation `init` = "glorot" (Glorot-uniform weights, TF's default that the official code
  gets; biases 0); "uniform" is the paper's text (U[-1, 1], which saturates the sigmoid),
  "torch" PyTorch's default.
- Grid stage: `cell_sizes` x `grid_depths` = Meng20's three grids; guides scale to [0, 255]
  (d = 255 in eq. (8)); any number of grids works (GuideNet then outputs G guides and G - 1
  weights, the last weight = 1 - the others). Grid sizes for H, W not divisible by s round up
  (`ops.bilateral_grid`), so `pad_multiple` = 1.
- w3 = 1 - w1 - w2 may be negative (as in the official code); the composed irradiance is
  clamped at 0 before remodulation (S of eq. (14) maps negatives to 0 anyway: the loss is
  unchanged).
- Network input S clips to [0, 1] (official `tone_mapping`; `guide_tonemap` = "gamma"), or
  log1p(x) unclipped (`guide_tonemap` = "log1p", as AFN / Isik21 read radiance: under S a
  light and a white wall beside it are both 1, so no guide can tell them apart); `gamma` =
  2.2 for the input and the loss (BMFR data; the Tungsten tone mapper of s.5 is not used).
  S(x) uses max(x, 1e-8) so that its gradient stays finite at black pixels.
- Depth scaling `depth_scale` "log": log1p(d) / log1p(max d) per frame (as AFN / WSKP; the
  official data uses a normalised depth PNG); "linear": d / max d.
- Loss: eq. (14) plus `temporal_weight` x the L1 of S-mapped frame differences when training
  asks for it (`denoise-train --temporal-weight`; Meng20 has no temporal term, so the demo is
  trained with 0). The official code's zeroing of gradients larger than 100 is not used.
- Outlier suppression (`outlier_suppression`, off: Meng20 uses it for 64-spp data only):
  luminance of the filmic-tonemapped radiance (official `tone_mapping` of outlier_lib), 3 x 3
  neighbours admitted where |albedo difference|^2 and |normal difference|^2 < `outlier_albedo`
  / `outlier_normal`, unbiased standard deviation over the admitted neighbours (the official
  kernel's loop skips neighbours of luminance 0, a quirk not kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from rtdenoise.ops.bilateral_grid import GUIDE_MAX, MENG20_GRIDS

from ..accumulation import (
    ACCUMULATION_INPUTS,
    ACCUMULATION_NOTE,
    ACCUMULATION_STATE,
    AccumulatingConfig,
    demodulate_and_accumulate,
)
from ..base import DenoiserModel, check_padding, pad_convs, register_family
from ..features import depth01
from ..ops.bilateral_grid import bilateral_grid

INPUT_CHANNELS = 10  # S(r_TA x albedo), albedo, normal, depth (Meng20 s.5)
GATE_CHANNELS = 3  # with `history_gate`: S(color), this frame's radiance
GATE_BIAS = 4.0  # the gate's initial logit: b = 0.98, nearly Meng20's r_TA
GAMMA_FLOOR = 1e-8  # S(x) = min(max(x, GAMMA_FLOOR)^(1/gamma), 1): finite gradient at 0
INITS = ("glorot", "uniform", "torch")
GUIDE_TONEMAPS = ("gamma", "log1p")


@dataclass(frozen=True)
class NBGConfig(AccumulatingConfig):
    """Sizes and constants of the NBG model (see the module docstring)."""

    family = "nbg"

    hidden: int = 20
    kernel_size: int = 5
    # (not in Meng20) hidden -> hidden convs between GuideNet's two, each with leaky ReLU
    middle_layers: int = 0
    middle_kernel_size: int = 3
    # (not in Meng20) a 1 x 1 conv from GuideNet's input added before its sigmoid (Gharbi17's
    # pointwise guide): guides may change at one pixel, where the k x k convs blur them
    pointwise_guide: bool = False
    # (not in Meng20) GuideNet also reads this frame's radiance and outputs a gate b per pixel:
    # the grids filter r + b (r_TA - r) instead of r_TA (a stale history: reflections, glass)
    history_gate: bool = False
    # (not in Meng20) GuideNet also reads TA's current-frame weight (1 where there is no history,
    # down to 0.2 where it has converged), as afn's `history_input`: frames without history are
    # 1 spp and want other guides than accumulated ones
    history_input: bool = False
    negative_slope: float = 0.2
    cell_sizes: tuple[int, ...] = tuple(s for s, _ in MENG20_GRIDS)
    grid_depths: tuple[int, ...] = tuple(d for _, d in MENG20_GRIDS)
    gamma: float = 2.2
    depth_scale: str = "log"  # "log" or "linear"
    init: str = "glorot"  # "glorot", "uniform" (Meng20 s.5) or "torch"
    outlier_suppression: bool = False
    outlier_sigma: float = 3.0
    outlier_albedo: float = 0.1
    outlier_normal: float = 0.1
    guide_tonemap: str = "gamma"  # GuideNet's radiance input: "gamma" (Meng20, clipped) or "log1p"
    padding: str = "zeros"  # GuideNet's convs past the frame's edge: "zeros" or "replicate"
    edge_margin: int = 0  # edge pixels repeated on every side, then cropped

    def validate(self) -> None:
        super().validate()  # AccumulatingConfig: the reprojection
        if self.hidden < 1:
            raise self.fail(f"hidden must be >= 1, got {self.hidden}")
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise self.fail(f"kernel_size must be odd, got {self.kernel_size}")
        if self.middle_layers < 0:
            raise self.fail(f"middle_layers must be >= 0, got {self.middle_layers}")
        if self.middle_kernel_size < 1 or self.middle_kernel_size % 2 == 0:
            raise self.fail(f"middle_kernel_size must be odd, got {self.middle_kernel_size}")
        if not self.cell_sizes or len(self.cell_sizes) != len(self.grid_depths):
            raise self.fail(
                f"cell_sizes {self.cell_sizes} and grid_depths {self.grid_depths} must be "
                "non-empty and of equal length (one (s, D) per grid)"
            )
        if any(s < 1 for s in self.cell_sizes) or any(d < 1 for d in self.grid_depths):
            raise self.fail("cell_sizes and grid_depths must be >= 1")
        if self.gamma <= 0:
            raise self.fail(f"gamma must be > 0, got {self.gamma}")
        if self.depth_scale not in ("log", "linear"):
            raise self.fail(f"depth_scale must be 'log' or 'linear', got {self.depth_scale!r}")
        if self.guide_tonemap not in GUIDE_TONEMAPS:
            raise self.fail(
                f"guide_tonemap must be one of {GUIDE_TONEMAPS}, got {self.guide_tonemap!r}"
            )
        if self.init not in INITS:
            raise self.fail(f"init must be one of {INITS}, got {self.init!r}")
        check_padding(self)
        if self.outlier_sigma <= 0:
            raise self.fail(f"outlier_sigma must be > 0, got {self.outlier_sigma}")

    @property
    def grids(self) -> int:
        return len(self.cell_sizes)


def gamma_map(x: torch.Tensor, gamma: float) -> torch.Tensor:
    """S(x) = clip(max(x, 0)^(1 / gamma), 0, 1) (Meng20 eq. (14), the official tone_mapping),
    with the floor GAMMA_FLOOR instead of 0 (finite gradient at black pixels)."""
    return torch.clamp(torch.clamp(x, min=GAMMA_FLOOR) ** (1.0 / gamma), max=1.0)


def guide_radiance(radiance: torch.Tensor, config: NBGConfig) -> torch.Tensor:
    """GuideNet's radiance channels: S(x) (Meng20 s.5, clipped at 1) or log1p(max(x, 0)), which
    keeps a light apart from a white wall beside it (both are 1 under S)."""
    if config.guide_tonemap == "log1p":
        return torch.log1p(torch.clamp(radiance, min=0.0))
    return gamma_map(radiance, config.gamma)


def _filmic(x: torch.Tensor) -> torch.Tensor:
    """The official outlier_lib tone map: x (6.2 x + 0.5) / (x (6.2 x + 1.7) + 0.06), x =
    max(r - 0.004, 0) (Hejl-Burgess)."""
    x = torch.clamp(x - 0.004, min=0.0)
    return x * (6.2 * x + 0.5) / (x * (6.2 * x + 1.7) + 0.06)


def suppress_outliers(
    color: torch.Tensor, albedo: torch.Tensor, normal: torch.Tensor, config: NBGConfig
) -> torch.Tensor:
    """Replace pixels whose tonemapped luminance is > sigma standard deviations from their
    similar 3 x 3 neighbours' by those neighbours' mean radiance (Meng20 s.5, official
    outlier_lib). Neighbours: in bounds, squared albedo and normal differences below the
    thresholds; pixels with fewer than 2 admitted neighbours are kept."""
    h, w = color.shape[-2:]
    tm = _filmic(color)
    gray = 0.2989 * tm[:, 0:1] + 0.5870 * tm[:, 1:2] + 0.1140 * tm[:, 2:3]
    stack = torch.cat((color, gray, albedo, normal, torch.ones_like(gray)), dim=1)
    padded = F.pad(stack, (1, 1, 1, 1))  # zeros: the last channel marks in-bounds taps
    count = torch.zeros_like(gray)
    g_sum, g_sq = torch.zeros_like(gray), torch.zeros_like(gray)
    c_sum = torch.zeros_like(color)
    for dy in range(3):
        for dx in range(3):
            if dy == 1 and dx == 1:
                continue
            q = padded[:, :, dy : dy + h, dx : dx + w]
            d_albedo = ((q[:, 4:7] - albedo) ** 2).sum(1, keepdim=True)
            d_normal = ((q[:, 7:10] - normal) ** 2).sum(1, keepdim=True)
            ok = (q[:, 10:11] > 0.5) & (d_albedo < config.outlier_albedo)
            ok = (ok & (d_normal < config.outlier_normal)).to(color.dtype)
            count = count + ok
            g_sum = g_sum + ok * q[:, 3:4]
            g_sq = g_sq + ok * q[:, 3:4] ** 2
            c_sum = c_sum + ok * q[:, 0:3]
    safe = torch.clamp(count, min=1.0)
    mean = g_sum / safe
    var = torch.clamp(g_sq / safe - mean**2, min=0.0) * count / torch.clamp(count - 1.0, min=1.0)
    outlier = (count > 1.5) & ((gray - mean).abs() > config.outlier_sigma * torch.sqrt(var))
    return torch.where(outlier, c_sum / safe, color)


class GuideNet(nn.Module):
    """Meng20 Fig. 2 (left): conv k x k in -> hidden, leaky ReLU, conv k x k hidden -> out,
    sigmoid; with `middle_layers` (0 in Meng20) hidden -> hidden convs, each with leaky ReLU,
    between the two, and with `pointwise_guide` a 1 x 1 conv in -> out added before the sigmoid
    (initialised to 0: the same guides as without it until training moves it)."""

    def __init__(self, in_channels: int, out_channels: int, config: NBGConfig) -> None:
        super().__init__()
        pad = config.kernel_size // 2
        self.conv1 = nn.Conv2d(in_channels, config.hidden, config.kernel_size, padding=pad)
        k = config.middle_kernel_size
        self.middle = nn.ModuleList(
            nn.Conv2d(config.hidden, config.hidden, k, padding=k // 2)
            for _ in range(config.middle_layers)
        )
        self.conv2 = nn.Conv2d(config.hidden, out_channels, config.kernel_size, padding=pad)
        self.negative_slope = config.negative_slope
        for conv in (self.conv1, *self.middle, self.conv2):
            if config.init == "glorot":
                nn.init.xavier_uniform_(conv.weight)
                nn.init.zeros_(conv.bias)
            elif config.init == "uniform":  # Meng20 s.5: "uniform random values from -1 to 1"
                nn.init.uniform_(conv.weight, -1.0, 1.0)
                nn.init.uniform_(conv.bias, -1.0, 1.0)
        # built after the others' init: under one seed they match those of a model without it
        self.pointwise = nn.Conv2d(in_channels, out_channels, 1) if config.pointwise_guide else None
        if self.pointwise is not None:
            nn.init.zeros_(self.pointwise.weight)
            nn.init.zeros_(self.pointwise.bias)
        pad_convs(self, config.padding)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = F.leaky_relu(self.conv1(x), self.negative_slope)
        for conv in self.middle:
            h = F.leaky_relu(conv(h), self.negative_slope)
        logits = self.conv2(h)
        if self.pointwise is not None:
            logits = logits + self.pointwise(x)  # Gharbi17's pointwise guidance map
        return torch.sigmoid(logits)


@register_family
class NBG(DenoiserModel):
    """Meng20 neural bilateral grid denoiser with temporal accumulation (module docstring)."""

    family = "nbg"
    config_class = NBGConfig
    example_config = {"hidden": 8}
    inputs = ACCUMULATION_INPUTS
    state_specs = ACCUMULATION_STATE
    pad_multiple = 1
    input_note = ACCUMULATION_NOTE

    def __init__(self, config: NBGConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = NBGConfig.of(config)
        # G guides and G - 1 composition weights (Meng20 Fig. 2: 3 + 2 = 5), and the gate
        gate = 1 if config.history_gate else 0
        in_channels = INPUT_CHANNELS + GATE_CHANNELS * gate + int(config.history_input)
        self.guide_net = GuideNet(in_channels, 2 * config.grids - 1 + gate, config)
        if gate:
            with torch.no_grad():
                self.guide_net.conv2.bias[-1] = GATE_BIAS

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg = self.cfg
        # 0. Optional outlier suppression of the noisy radiance (Meng20 s.5).
        if cfg.outlier_suppression:
            color = torch.clamp(buffers["color"], min=0.0)
            albedo = torch.clamp(buffers["albedo"], min=0.0)
            buffers = dict(buffers, color=suppress_outliers(color, albedo, buffers["normal"], cfg))

        # 1-2. Albedo demodulation and temporal accumulation, history weight 0.8 (s.4.1, s.4.6).
        frame = demodulate_and_accumulate(buffers, state, reset, cfg)
        r_ta = frame.accumulated

        # 3. GuideNet input (s.5): radiance with albedo (S or log1p), albedo, normal, depth.
        radiance = guide_radiance(r_ta * frame.modulation, cfg)
        normal01 = 0.5 * (frame.normal + 1.0)
        depth_01 = depth01(frame.depth, cfg.depth_scale)
        features = [radiance, frame.albedo, normal01, depth_01]
        if cfg.history_gate:  # (not in Meng20) this frame's radiance beside the history's
            features.append(guide_radiance(frame.color, cfg))
        if cfg.history_input:  # (not in Meng20) how much of r_TA is this frame: 1 = no history
            features.append(frame.blend)
        net_out = self.guide_net(torch.cat(features, dim=1))

        # 4. Guides in [0, 255] and composition weights (s.4.1, s.4.5).
        g = cfg.grids
        guides = GUIDE_MAX * net_out[:, :g]
        weights = net_out[:, g : 2 * g - 1]
        last = 1.0 - weights.sum(dim=1, keepdim=True)
        grid_input = r_ta
        if cfg.history_gate:  # from this frame's irradiance (b = 0) to r_TA (b = 1)
            gate = net_out[:, 2 * g - 1 :]
            grid_input = frame.irradiance + gate * (r_ta - frame.irradiance)

        # 5-6. One bilateral grid per scale on the HDR irradiance, composed by eq. (15).
        composed = None
        for k, (s, d) in enumerate(zip(cfg.cell_sizes, cfg.grid_depths, strict=True)):
            sliced = bilateral_grid(grid_input, guides[:, k : k + 1], s, d)  # eqs. (10)-(13)
            w_k = weights[:, k : k + 1] if k < g - 1 else last
            composed = w_k * sliced if composed is None else composed + w_k * sliced

        # 7. Remodulation (s.4.3).
        return torch.clamp(composed, min=0.0) * frame.modulation, frame.state

    def loss(
        self, outputs: torch.Tensor, reference: torch.Tensor, temporal_weight: float
    ) -> torch.Tensor:
        """Meng20 eq. (14): mean |S(output) - S(reference)| over (B, T, 3, H, W), plus
        temporal_weight x the same L1 on frame differences (0 in Meng20)."""
        s_out = gamma_map(outputs, self.cfg.gamma)
        s_ref = gamma_map(reference, self.cfg.gamma)
        loss = (s_out - s_ref).abs().mean()
        if temporal_weight and outputs.shape[1] > 1:
            d_out = s_out[:, 1:] - s_out[:, :-1]
            d_ref = s_ref[:, 1:] - s_ref[:, :-1]
            loss = loss + temporal_weight * (d_out - d_ref).abs().mean()
        return loss


__all__ = [
    "GATE_CHANNELS",
    "INPUT_CHANNELS",
    "NBG",
    "GuideNet",
    "NBGConfig",
    "gamma_map",
    "suppress_outliers",
]
