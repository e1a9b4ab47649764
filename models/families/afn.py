"""AFN: real-time Monte Carlo denoising with an adaptive fusion network (Lee24).

`AFN.forward` reads like Lee24 Fig. 1:

1. demodulate (III-A): irradiance r = color / (albedo + albedo_eps);
2. temporal accumulation (III-A, "TA as in [2], [8], [17]"): `models.temporal` reprojects the
   previous accumulation with the motion vectors, rejects it on depth / normal disagreement
   or off-screen, and blends (moving average, weight max(min_alpha, 1 / (history + 1)));
3. network input (III-A): tonemapped r_1spp and r_TA, albedo, normal in [0, 1], depth scaled
   to [0, 1] per frame (+ the TA blend weight, see below);
4. multi-scale kernel prediction M (III-B, eq. (1)): a light U-Net autoencoder; K_1spp (k x k
   taps, softmax) is sliced from the 1/2-scale decoder feature, K_TA (softmax) from the
   full-scale one (with `fusion` = "head" also the fusion weight alpha, a sigmoid channel);
5. filtering (III-C, eq. (2)) on HDR values: d_1spp = KernelApply(D r_1spp, K_1spp) at half
   resolution, d_TA = KernelApply(r_TA, K_TA) at full resolution, each as one
   SoftmaxKernelApply op that takes the kernel's logits (the softmax happens inside it);
6. adaptive fusion (eq. (3)): i = d_TA - alpha U D d_TA + alpha U d_1spp; with `fusion` =
   "network" alpha comes from the fusion module F of Fig. 2 (c), a small CNN that sees the
   filtered images (Vogels18's scale compositor: `FusionNet`);
7. refinement (eq. (4)): o = i + R(i, f), a small conv net;
8. remodulate: output = o * (albedo + albedo_eps).

Steps 1-2 are the shared opening `models.accumulation.demodulate_and_accumulate`.

Choices the paper leaves open (all in `AFNConfig`, stored in checkpoints):
- albedo_eps = 1e-2 in demodulation and remodulation (exactly invertible; zero albedo, e.g.
  the background, keeps its radiance as 100 x irradiance).
- TA: `models.temporal.TemporalConfig` (relative depth tolerance 0.1, normal dot > 0.9,
  min_alpha 0.2 = Meng20's history weight 0.8). History lives in the `ta` state (r_TA and the
  history length) and the `geometry` state (normal and depth of the last frame).
- Tonemap of the network input: log1p (Bako17, the [6] that Lee24 cites for HDR inputs).
- Depth scaling "log": log1p(d) / log1p(max d) per frame (maps [0, max] to [0, 1] like the
  paper's linear scaling, but keeps resolution on the foreground when the background depth
  is huge, e.g. 1e4); "linear": d / max d (the paper's text).
- `history_input`: the TA blend weight a (1 on fresh pixels, min_alpha on converged ones) is
  an extra input channel so the network knows how reliable r_TA is (not in the paper).
- Autoencoder ("light-weight", III-B, timed at 1.46 ms per 720p frame on an RTX 2080 Ti, i.e.
  about 8 k multiply-adds per pixel): `widths` per scale (default 16, 12, 16, 24, 32 at 1,
  1/2, ..., 1/16), 3 x 3 convs + ReLU, two per block below full scale; 2 x 2 average pooling
  down, nearest 2 x upsampling + skip concatenation up. Heads are 1 x 1 convs. Kernel size 7
  for both kernels (the paper's k). Every conv at full scale costs 4 x its 1/2-scale twin, yet
  K_TA and alpha are sliced there: the full scale keeps 16 channels (the kernels' 49 taps come
  from them) but few convs, `full_res_convs` (1) in the encoder and decoder blocks, and the
  decoder's are `full_res_decoder_kernel` x `full_res_decoder_kernel` (1: they mix the
  upsampled context with the skip per pixel; the encoder's 3 x 3 sees the neighbourhood).
  Trained like the demo, this default scores 27.29 dB on the committed sequences (the former
  83.9 GFLOP default 27.20); an 8-channel full scale (widths 8, 12, 16, 24, one 3 x 3
  full-scale conv per block, 12.9 GFLOP) scored 26.30 dB, and widths 8, 12, 16, 24, 32 with
  two full-scale convs (13.7 GFLOP) followed its training loss to step 850 (stopped there).
- Refinement R ("small", 0.89 ms in Lee24 Table 10): `refine_layers` (2) 3 x 3 convs of width
  `refine_width` (4) on [log1p(i), albedo, normal, depth]; the residual is added in the log1p
  domain, o = expm1(max(log1p(max(i, 0)) + R, 0)), which keeps the output >= 0 (the fused
  image can be slightly negative: eq. (3) is an unsharp-mask-like difference). Small because
  it earned nothing in our training: the former demo (width 16, 3 layers, 7.7 GFLOP) scored
  27.23 dB on the committed sequences with its residual set to zero, 27.20 dB with it.
- `fusion`: "head" (default, as demo:afn was trained): alpha is a sigmoid channel of the
  kernel predictor's full-scale head, blind to the filtered images; "network": Lee24 Fig. 2
  (c), alpha = FusionNet(log1p d_TA, log1p U D d_TA, log1p U d_1spp, features), two 3 x 3
  convs of `fusion_width` (8) channels, ReLU, sigmoid: it sees where d_1spp and d_TA disagree
  (a moving light, a disocclusion). The figure's layer sizes are not in the text: these are
  the smallest that see a 5 x 5 neighbourhood; 1.2 k multiply-adds per pixel.
- `padding`: how every k x k convolution sees past the frame's edge, "zeros" (default, as
  the paper's code and the demos before 2026-12-05) or "replicate" (the edge pixel repeated).
  With zeros a small light at the frame's edge reads as a bright pixel beside a black one, and
  demo:afn smeared the committed emitter strip into the first two columns (7.11 where the
  reference is 0.055; benchmarks/README.md, "afn's frame 7").
- `edge_margin` (0): pixels of the frame's edge repeated on every side before the network and
  cropped from its output (`DenoiserModel.edge_margin`, contract key `rtdenoise.edge_margin`):
  weights that smear a light at the frame's edge into the first columns keep it in place when
  the edge lies `edge_margin` pixels inside what they see.
- H and W must be multiples of `pad_multiple` = 2 ** (len(widths) - 1).

Cost (FLOP = 2 x multiply-adds of the Conv layers, `benchmarks/flops.py`): the defaults take
6.94 k multiply-adds per pixel, 12.8 GFLOP per 1280 x 720 frame (predictor 11.9, refinement
0.9), within Lee24's budget (<= 14). `LEGACY_CONFIG` (widths 24, 32, 48, refinement width 16,
two 3 x 3 convs in every block; 45.5 k, 83.9 GFLOP) is the model the demo shipped before.
Checkpoints store their whole config and rebuild the model they were trained as; those saved
before the full-scale options existed get what they had then (`AFNConfig.from_dict`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..accumulation import (
    ACCUMULATION_INPUTS,
    ACCUMULATION_NOTE,
    ACCUMULATION_STATE,
    AccumulatingConfig,
    demodulate_and_accumulate,
)
from ..base import DenoiserModel, check_padding, pad_convs, parameter_count, register_family
from ..features import depth01
from ..ops.adaptive_fusion import adaptive_fusion
from ..ops.softmax_kernel_apply import softmax_kernel_apply


@dataclass(frozen=True)
class AFNConfig(AccumulatingConfig):
    """Sizes and constants of the AFN model (see the module docstring)."""

    family = "afn"

    widths: tuple[int, ...] = (16, 12, 16, 24, 32)
    kernel_size: int = 7
    refine_width: int = 4
    refine_layers: int = 2
    depth_scale: str = "log"  # "log" or "linear"
    history_input: bool = True
    full_res_convs: int = 1  # convs in the full-scale encoder and decoder blocks
    full_res_decoder_kernel: int = 1  # their kernel size in the decoder block
    fusion: str = "head"  # where alpha comes from: "head" (predictor) or "network" (Fig. 2c)
    fusion_width: int = 8  # FusionNet's hidden channels
    padding: str = "zeros"  # past the frame's edge: "zeros" or "replicate" (every k x k conv)
    edge_margin: int = 0  # edge pixels repeated on every side, then cropped

    @classmethod
    def from_dict(cls, data: dict | None) -> AFNConfig:
        """As `FamilyConfig.from_dict`, except that a complete config saved before a field
        existed (every key of `_PRE_LIGHT_KEYS`, as `to_dict` wrote it into checkpoints and
        ONNX metadata) gets the value that field had then, not today's default: an old
        checkpoint rebuilds the model it was trained as."""
        data = dict(data or {})
        if _PRE_LIGHT_KEYS <= set(data):
            for key, value in _ADDED_FIELDS.items():
                data.setdefault(key, value)
        return super().from_dict(data)

    def validate(self) -> None:
        super().validate()  # AccumulatingConfig: the reprojection
        if len(self.widths) < 2 or any(w < 1 for w in self.widths):
            raise self.fail(f"widths must list >= 2 positive sizes, got {self.widths}")
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise self.fail(f"kernel_size must be odd, got {self.kernel_size}")
        if self.full_res_decoder_kernel < 1 or self.full_res_decoder_kernel % 2 == 0:
            k = self.full_res_decoder_kernel
            raise self.fail(f"full_res_decoder_kernel must be odd, got {k}")
        if self.full_res_convs < 1:
            raise self.fail(f"full_res_convs must be >= 1, got {self.full_res_convs}")
        if self.refine_layers < 1:
            raise self.fail(f"refine_layers must be >= 1, got {self.refine_layers}")
        if self.depth_scale not in ("log", "linear"):
            raise self.fail(f"depth_scale must be 'log' or 'linear', got {self.depth_scale!r}")
        if self.fusion not in ("head", "network"):
            raise self.fail(f"fusion must be 'head' or 'network', got {self.fusion!r}")
        if self.fusion_width < 1:
            raise self.fail(f"fusion_width must be >= 1, got {self.fusion_width}")
        check_padding(self)


# The AFNConfig keys of every checkpoint saved before the full-scale options were added, and
# the value each added field had implicitly then (two 3 x 3 convs per full-scale block).
_PRE_LIGHT_KEYS = frozenset(
    ("widths", "kernel_size", "refine_width", "refine_layers", "depth_scale", "history_input")
    + ("albedo_eps", "depth_tolerance", "normal_threshold", "min_alpha", "max_history")
)
_ADDED_FIELDS = {"full_res_convs": 2, "full_res_decoder_kernel": 3}

# The model demo:afn shipped before the light default (83.9 GFLOP per 720p frame).
LEGACY_CONFIG = {
    "widths": [24, 32, 48],
    "refine_width": 16,
    "refine_layers": 3,
    "full_res_convs": 2,
    "full_res_decoder_kernel": 3,
}


def _conv_block(c_in: int, c_out: int, convs: int = 2, kernel: int = 3) -> nn.Sequential:
    mods: list[nn.Module] = []
    for i in range(convs):
        conv = nn.Conv2d(c_in if i == 0 else c_out, c_out, kernel, padding=kernel // 2)
        mods += [conv, nn.ReLU(inplace=True)]
    return nn.Sequential(*mods)


class KernelPredictor(nn.Module):
    """Lee24 eq. (1): M(r_1spp, r_TA, f) -> K_1spp (1/2 scale), K_TA and alpha (full scale).

    The kernels are returned as logits: their softmax over the k*k taps is taken inside the
    filter op (`softmax_kernel_apply`), so the normalised kernels are never stored. Without
    `alpha_head` (alpha from `FusionNet`) the third output is None."""

    def __init__(
        self,
        in_channels: int,
        widths: tuple[int, ...],
        kernel_size: int,
        full_res_convs: int = 2,
        full_res_decoder_kernel: int = 3,
        alpha_head: bool = True,
    ) -> None:
        super().__init__()
        taps = kernel_size * kernel_size
        convs = [full_res_convs] + [2] * (len(widths) - 1)  # per scale
        self.encoders = nn.ModuleList()
        c = in_channels
        for w, n in zip(widths, convs, strict=True):
            self.encoders.append(_conv_block(c, w, n))
            c = w
        # decoders[l] produces the feature at scale 1 / 2**l from the one below and skip l.
        self.decoders = nn.ModuleList(
            _conv_block(
                widths[level + 1] + widths[level],
                widths[level],
                convs[level],
                full_res_decoder_kernel if level == 0 else 3,
            )
            for level in range(len(widths) - 1)
        )
        self.head_1spp = nn.Conv2d(widths[1], taps, 1)
        self.head_ta = nn.Conv2d(widths[0], taps + int(alpha_head), 1)
        self.taps = taps
        self.alpha_head = alpha_head

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        skips = []
        for level, encoder in enumerate(self.encoders):
            if level > 0:
                x = F.avg_pool2d(x, 2)
            x = encoder(x)
            skips.append(x)
        features = [x]
        for level in range(len(self.decoders) - 1, -1, -1):
            up = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = self.decoders[level](torch.cat((up, skips[level]), dim=1))
            features.append(x)
        half, full = features[-2], features[-1]
        logits_1spp = self.head_1spp(half)
        head = self.head_ta(full)
        if not self.alpha_head:
            return logits_1spp, head, None
        alpha = torch.sigmoid(head[:, self.taps :])
        return logits_1spp, head[:, : self.taps], alpha


class FusionNet(nn.Module):
    """Lee24 Fig. 2 (c), the fusion module F's weight: alpha from the filtered images (a
    Vogels18 scale compositor), log1p-tonemapped, and the features."""

    def __init__(self, feature_channels: int, width: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(9 + feature_channels, width, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, 1, 3, padding=1),
        )

    def forward(
        self, d_ta: torch.Tensor, d_1spp: torch.Tensor, features: torch.Tensor
    ) -> torch.Tensor:
        coarse_ta = F.interpolate(F.avg_pool2d(d_ta, 2), scale_factor=2.0, mode="nearest")  # U D
        up_1spp = F.interpolate(d_1spp, scale_factor=2.0, mode="nearest")  # U
        images = torch.cat((d_ta, coarse_ta, up_1spp), dim=1)
        x = torch.cat((torch.log1p(torch.clamp(images, min=0.0)), features), dim=1)
        return torch.sigmoid(self.net(x))


class Refinement(nn.Module):
    """Lee24 eq. (4): the residual R(i, f), a plain conv net (ReLU between layers)."""

    def __init__(self, in_channels: int, width: int, layers: int) -> None:
        super().__init__()
        mods: list[nn.Module] = []
        c = in_channels
        for _ in range(layers - 1):
            mods += [nn.Conv2d(c, width, 3, padding=1), nn.ReLU(inplace=True)]
            c = width
        last = nn.Conv2d(c, 3, 3, padding=1)
        with torch.no_grad():  # start close to the identity o = i, but keep gradients alive
            last.weight.mul_(0.1)
            last.bias.zero_()
        mods.append(last)
        self.net = nn.Sequential(*mods)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


@register_family
class AFN(DenoiserModel):
    """Lee24 adaptive fusion network with temporal accumulation (see the module docstring)."""

    family = "afn"
    config_class = AFNConfig
    example_config = {"widths": [8, 12, 16], "kernel_size": 5, "refine_width": 8}
    inputs = ACCUMULATION_INPUTS
    state_specs = ACCUMULATION_STATE
    input_note = ACCUMULATION_NOTE

    def __init__(self, config: AFNConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = AFNConfig.of(config)
        self.pad_multiple = 2 ** (len(config.widths) - 1)
        # r_1spp (3) + r_TA (3) + albedo (3) + normal (3) + depth (1) [+ TA weight (1)]
        in_channels = 13 + int(config.history_input)
        self.predictor = KernelPredictor(
            in_channels,
            config.widths,
            config.kernel_size,
            config.full_res_convs,
            config.full_res_decoder_kernel,
            alpha_head=config.fusion == "head",
        )
        self.fusion = FusionNet(7, config.fusion_width) if config.fusion == "network" else None
        self.refine = Refinement(7 + 3, config.refine_width, config.refine_layers)
        pad_convs(self, config.padding)

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        # 1-2. Demodulation and temporal accumulation (Lee24 III-A): r_1spp, r_TA, weight a.
        frame = demodulate_and_accumulate(buffers, state, reset, self.cfg)
        r_1spp, r_ta = frame.irradiance, frame.accumulated

        # 3. Network input: tonemapped radiance, features scaled to [0, 1] (Lee24 III-A).
        depth_01 = depth01(frame.depth, self.cfg.depth_scale)
        features = torch.cat((frame.albedo, 0.5 * (frame.normal + 1.0), depth_01), dim=1)
        net_in = [torch.log1p(r_1spp), torch.log1p(r_ta), features]
        if self.cfg.history_input:
            net_in.append(frame.blend)

        # 4. Multi-scale kernel prediction, Lee24 eq. (1).
        logits_1spp, logits_ta, alpha = self.predictor(torch.cat(net_in, dim=1))

        # 5. Filtering on HDR values, Lee24 eq. (2): 1 spp at 1/2 scale, TA at full scale,
        # each kernel the softmax of its logits over the k x k taps.
        d_1spp = softmax_kernel_apply(F.avg_pool2d(r_1spp, 2), logits_1spp)
        d_ta = softmax_kernel_apply(r_ta, logits_ta)

        # 6. Adaptive fusion, Lee24 eq. (3), alpha from the fusion module F (Fig. 2c) or the head.
        if self.fusion is not None:
            alpha = self.fusion(d_ta, d_1spp, features)
        fused = adaptive_fusion(d_ta, d_1spp, alpha)

        # 7. Refinement, Lee24 eq. (4), residual in the log1p domain (output >= 0).
        log_fused = torch.log1p(torch.clamp(fused, min=0.0))
        residual = self.refine(torch.cat((log_fused, features), dim=1))
        refined = torch.expm1(torch.clamp(log_fused + residual, min=0.0))

        # 8. Remodulation.
        return refined * frame.modulation, frame.state


__all__ = [
    "AFN",
    "AFNConfig",
    "FusionNet",
    "LEGACY_CONFIG",
    "KernelPredictor",
    "Refinement",
    "parameter_count",
]
