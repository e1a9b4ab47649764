"""Affinity: interactive Monte Carlo denoising with the affinity of neural features (Isik21).

`Affinity.forward` reads like Isik21 Fig. 2:

1. per-sample input (3.1): every sample of the pixel brings its features r_xyst (config
   `sample_features`, canonical buffer names; runtime/sequences/samples.py); the pixel
   radiance L is the mean of the samples' linear radiance;
2. per-sample embedding (3.2, eq. (1)): a pointwise FC net (`embed_layers` x `embed_width`,
   leaky ReLU) on every sample, averaged over the samples: e_t (1 x 1 convs + a mean, in ONNX
   Conv and ReduceMean over a dynamic S);
3. warp (3.3): the previous state, nearest-neighbour at p + motion (`ops.reproject` with
   nearest = 1, one op per state tensor), masked where the reprojection is invalid (see below);
4. U-Net (3.3, eq. (2)) on [e_t, W e_{t-1}] ->
   per kernel k: features f^k (d), bandwidth a^k = x^2, centre weight c^k = sigmoid(x);
   temporal bandwidth b = x^2 and accumulation weight lambda = sigmoid(x);
5. temporal accumulation (eq. (3), (5)): e_t <- (1 - lambda) e_t + lambda W e_{t-1}, and the
   same for L (eq. (5) read with L_{t-1}, as its typo is read by every implementation);
6. K - 1 dilated spatial kernels (3.4-3.5.1, eq. (4), (6)): L^(k) = AffinityFilter(L^(k-1)),
   dilation 2^(k-1), starting from the accumulated L;
7. the last spatial kernel (dilation 2^(K-1)) and the temporal kernel over the warped previous
   output (eq. (7)-(8)), normalised jointly: O_t = TemporalAffinityFilter(...).

The kernel size is a run-time option (Isik21 3.6, Fig. 7): the buffer `option_kernel_size`
feeds every kernel, exported as the overridable initializer `option.kernel_size`
(`Denoiser(..., overrides={"kernel_size": 7})`, `denoise-run --kernel-size 7`).

Choices the paper leaves open (all in `AffinityConfig`, stored in checkpoints):
- Per-sample features: Mitsuba has no diffuse / specular split, roughness or material flags,
  so the default is ("color", "albedo", "normal", "depth"): 10 channels instead of the
  paper's 18 (radiance log1p-tonemapped, albedo and normal as they are, depth
  log1p(d) / log1p(max d) per frame). A file without per-sample layers gives S = 1 from its
  pixel means.
- The FC net applies its leaky ReLU after each of its 3 layers; leaky slope 0.01.
- U-Net: `encoder` widths (64, 64, 64, 80), `bottleneck` 96, `decoder` (80, 64, 64, 32): two
  3 x 3 convs + leaky ReLU per level, 2 x 2 max pooling, bilinear 2 x upsampling, skips
  concatenated; a last 3 x 3 conv (no activation) gives the K (d + 2) + 2 parameters
  (32 for K = 3, d = 8: the paper's last c32). 941,664 parameters with the paper's 18
  per-sample features (938,944 U-Net + 2,720 FC). H and W are padded to 16.
- Reprojection validity: inside the previous frame and, with normal and depth among the
  sample features, the sample-mean depth and normal of the pixel agree with the warped ones
  (relative depth 0.1, normal dot 0.9, like the other families' history test); reset
  invalidates everything. Where invalid, the warped embedding and radiance are replaced by
  the current ones (e_0 at t = 0, as the paper initialises eq. (3), (5)) and the temporal
  kernel's taps weigh 0 (omega = 0 at t = 0).
- Temporal kernel size `temporal_size` 0 = the spatial kernel size (also at run time).
- Losses (eq. (9)-(13), `loss`): SMAPE with the L1 norm of the colour vector per pixel
  (eq. (11), eps `smape_eps` 1e-2) + temporal_weight (0.25) x SMAPE of the frame differences
  + 1e-5 x (sum_k E a_k^2 + E b^2); the bandwidths of the last forward passes are kept for
  the regulariser while training.
- `padding`: how every 3 x 3 convolution of the U-Net sees past the frame's edge, "zeros"
  (default, as the paper's code) or "replicate" (the edge pixel repeated), as afn's key.
- `edge_margin` (0): pixels of the frame's edge repeated on every side before the network and
  cropped from its output (`DenoiserModel.edge_margin`, contract key `rtdenoise.edge_margin`):
  weights that smear a light at the frame's edge into the first columns keep it in place when
  the edge lies `edge_margin` pixels inside what they see.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from rtdenoise.ops.affinity_filter import MAX_KERNEL_SIZE
from rtdenoise.runtime.sequences.samples import (
    DEFAULT_SAMPLE_FEATURES,
    check_features,
    feature_channels,
    feature_offsets,
)

from ..base import (
    DenoiserModel,
    FamilyConfig,
    RuntimeOption,
    StateSpec,
    check_padding,
    pad_convs,
    parameter_count,
    register_family,
)
from ..ops.affinity_filter import affinity_filter
from ..ops.reproject import reproject
from ..ops.temporal_affinity_filter import temporal_affinity_filter


@dataclass(frozen=True)
class AffinityConfig(FamilyConfig):
    """Sizes and constants of the affinity model (see the module docstring)."""

    family = "affinity"

    sample_features: tuple[str, ...] = DEFAULT_SAMPLE_FEATURES
    embed_width: int = 32  # Isik21 3.2: 3 layers of 32
    embed_layers: int = 3
    encoder: tuple[int, ...] = (64, 64, 64, 80)  # Isik21 3.3: c64c64d c64c64d c64c64d c80c80d
    bottleneck: int = 96  # c96c96u
    decoder: tuple[int, ...] = (80, 64, 64, 32)  # c80c80u c64c64u c64c64u c32(c32)
    kernels: int = 3  # K
    feature_dim: int = 8  # d
    kernel_size: int = 13  # taps per side (3.5.1)
    temporal_size: int = 0  # 0: the kernel size
    leaky_slope: float = 0.01
    depth_tolerance: float = 0.1
    normal_threshold: float = 0.9
    smape_eps: float = 1e-2
    temporal_weight: float = 0.25  # eq. (9), unless training overrides it
    regulariser_weight: float = 1e-5  # eq. (9)
    padding: str = "zeros"  # past the frame's edge: "zeros" or "replicate"
    edge_margin: int = 0  # edge pixels repeated on every side, then cropped

    def validate(self) -> None:
        check_padding(self)
        try:
            features = check_features(self.sample_features)
        except ValueError as exc:
            raise self.fail(str(exc)) from None
        if "color" not in features:
            raise self.fail(f"sample_features must include 'color', got {list(features)}")
        if not self.encoder or len(self.decoder) != len(self.encoder):
            raise self.fail(
                f"decoder needs one width per encoder level, got {self.encoder} / {self.decoder}"
            )
        widths = (*self.encoder, self.bottleneck, *self.decoder, self.embed_width)
        if min(widths) < 1 or self.embed_layers < 1 or self.feature_dim < 1:
            raise self.fail("widths, embed_layers and feature_dim must be >= 1")
        if self.kernels < 1:
            raise self.fail(f"kernels must be >= 1, got {self.kernels}")
        for name in ("kernel_size", "temporal_size"):
            k = getattr(self, name)
            if not (k == 0 and name == "temporal_size") and (
                k < 1 or k % 2 == 0 or k > MAX_KERNEL_SIZE
            ):
                raise self.fail(f"{name} must be an odd integer in [1, {MAX_KERNEL_SIZE}], got {k}")

    @property
    def parameter_channels(self) -> int:
        """U-Net outputs: K x (f^k, a^k, c^k), b, lambda (Isik21 eq. (2))."""
        return self.kernels * (self.feature_dim + 2) + 2


def _kernel_size_option(name: str, default: int, doc: str) -> RuntimeOption:
    """A kernel size the runtime may change: an odd integer in [1, MAX_KERNEL_SIZE]."""
    return RuntimeOption(name, default, doc, 1, MAX_KERNEL_SIZE, True)


def _conv(c_in: int, c_out: int) -> nn.Conv2d:
    return nn.Conv2d(c_in, c_out, 3, padding=1)


class Embedding(nn.Module):
    """Isik21 eq. (1): e = mean_s FC(r_s), the FC net applied to every sample (1 x 1 convs)."""

    def __init__(self, in_channels: int, width: int, layers: int, slope: float) -> None:
        super().__init__()
        mods: list[nn.Module] = []
        c = in_channels
        for _ in range(layers):
            mods += [nn.Conv2d(c, width, 1), nn.LeakyReLU(slope)]
            c = width
        self.net = nn.Sequential(*mods)

    def forward(self, samples: torch.Tensor) -> torch.Tensor:
        """samples (N, S, C, H, W) -> (N, width, H, W)."""
        n, s, c, h, w = samples.shape
        e = self.net(samples.reshape(n * s, c, h, w))
        return e.reshape(n, s, e.shape[1], h, w).mean(dim=1)


class UNet(nn.Module):
    """Isik21 3.3: two 3 x 3 convs + leaky ReLU per level, 2 x 2 max pooling down, bilinear
    2 x upsampling and concatenated skips up, a last 3 x 3 conv without activation."""

    def __init__(
        self,
        in_channels: int,
        encoder: tuple[int, ...],
        bottleneck: int,
        decoder: tuple[int, ...],
        out_channels: int,
        slope: float,
    ) -> None:
        super().__init__()

        def block(c_in: int, c_out: int) -> nn.Sequential:
            return nn.Sequential(
                _conv(c_in, c_out), nn.LeakyReLU(slope), _conv(c_out, c_out), nn.LeakyReLU(slope)
            )

        self.down = nn.ModuleList()
        c = in_channels
        for width in encoder:
            self.down.append(block(c, width))
            c = width
        self.bottom = block(c, bottleneck)
        self.up = nn.ModuleList()
        c = bottleneck
        for level, width in zip(range(len(encoder) - 1, -1, -1), decoder, strict=True):
            if level > 0:
                self.up.append(block(c + encoder[level], width))
            else:  # the finest level: c32 + leaky ReLU, then the last conv (Isik21 "c32c32")
                self.up.append(
                    nn.Sequential(
                        _conv(c + encoder[level], width),
                        nn.LeakyReLU(slope),
                        _conv(width, out_channels),
                    )
                )
            c = width

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2)
        x = self.bottom(x)
        for block, skip in zip(self.up, reversed(skips), strict=True):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = block(torch.cat((x, skip), dim=1))
        return x


def inside_previous_frame(motion: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) bool: the pixel nearest to p + motion (previous = current + motion,
    docs/contract.md) lies inside the previous frame."""
    _, _, h, w = motion.shape
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype).view(1, 1, w)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype).view(1, h, 1)
    px = torch.floor(xs + motion[:, 0] + 0.5)
    py = torch.floor(ys + motion[:, 1] + 0.5)
    return ((px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)).unsqueeze(1)


def warp_nearest(x: torch.Tensor, motion: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Isik21's W_t: x (N, C, H, W) of the previous frame read at the nearest pixel of
    p + motion (Reproject with nearest = 1: one op, a copy), and where that pixel lies inside
    the previous frame (outside, the clamped border pixel is read)."""
    return reproject(x, motion, nearest=1), inside_previous_frame(motion)


@register_family
class Affinity(DenoiserModel):
    """Isik21 affinity-of-neural-features denoiser (see the module docstring)."""

    family = "affinity"
    config_class = AffinityConfig
    example_config = {
        "embed_width": 8,
        "encoder": [8, 8],
        "bottleneck": 8,
        "decoder": [8, 8],
        "feature_dim": 4,
        "kernel_size": 5,
    }
    inputs = ("samples", "motion")
    input_note = (
        "pass per-sample buffers (samples: S x C, the config's sample_features, radiance linear "
        "HDR, depth linear, normal in [-1, 1]; S = 1 from the pixel means works) and motion in "
        "pixels (previous = current + motion); do NOT tonemap, normalise or accumulate"
    )

    def __init__(self, config: AffinityConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = AffinityConfig.of(config)
        self.pad_multiple = 2 ** len(config.encoder)
        self.offsets = feature_offsets(config.sample_features)
        self.embedding = Embedding(
            feature_channels(config.sample_features),
            config.embed_width,
            config.embed_layers,
            config.leaky_slope,
        )
        self.unet = UNet(
            2 * config.embed_width,
            config.encoder,
            config.bottleneck,
            config.decoder,
            config.parameter_channels,
            config.leaky_slope,
        )
        pad_convs(self.unet, config.padding)
        self.state_specs = (
            StateSpec("embedding", config.embed_width),  # accumulated e (eq. (3))
            StateSpec("radiance", 3),  # accumulated L (eq. (5))
            StateSpec("features", config.feature_dim),  # f^K of the last kernel (eq. (7))
            StateSpec("output", 3),  # O (eq. (8))
            StateSpec("geometry", 4),  # sample-mean normal and depth (validity test)
        )
        size_doc = "odd taps per side of every affinity kernel (Isik21 Fig. 7: 7..19)"
        self.add_runtime_option(_kernel_size_option("kernel_size", config.kernel_size, size_doc))
        if config.temporal_size:
            doc = "odd taps per side of the temporal kernel"
            self.add_runtime_option(_kernel_size_option("temporal_size", config.temporal_size, doc))
        self._bandwidths: list[torch.Tensor] = []  # training: E a^2 + E b^2 per frame

    # -- 1. per-sample input ------------------------------------------------------------------

    def _feature(self, samples: torch.Tensor, name: str) -> torch.Tensor:
        c = self.offsets[name]
        return samples[:, :, c : c + (3 if name != "depth" else 1)]

    def _network_samples(self, samples: torch.Tensor) -> torch.Tensor:
        """The FC net's input: radiance log1p-tonemapped (Isik21 3.1), depth log-scaled to
        [0, 1] per frame, albedo and normal as they are."""
        parts = []
        for name in self.cfg.sample_features:
            x = self._feature(samples, name)
            if name in ("color", "color_b"):
                x = torch.log1p(torch.clamp(x, min=0.0))
            elif name == "depth":
                x = torch.log1p(torch.clamp(x, min=0.0))
                x = x / (x.amax(dim=(1, 2, 3, 4), keepdim=True) + 1e-6)
            parts.append(x)
        return torch.cat(parts, dim=2)

    def _geometry(self, samples: torch.Tensor) -> torch.Tensor | None:
        """(N, 4, H, W) sample-mean normal and depth, or None without those features."""
        if "normal" not in self.offsets or "depth" not in self.offsets:
            return None
        normal = self._feature(samples, "normal").mean(dim=1)
        depth = torch.clamp(self._feature(samples, "depth"), min=0.0).mean(dim=1)
        return torch.cat((normal, depth), dim=1)

    def _valid(
        self,
        inside: torch.Tensor,
        geometry: torch.Tensor | None,
        prev_geometry: torch.Tensor,
        reset: torch.Tensor,
    ) -> torch.Tensor:
        """(N, 1, H, W) float in {0, 1}: the warped previous frame may be used here."""
        valid = inside
        if geometry is not None:
            depth, prev_depth = geometry[:, 3:4], prev_geometry[:, 3:4]
            depth_ok = (prev_depth - depth).abs() < self.cfg.depth_tolerance * depth
            dot = (geometry[:, :3] * prev_geometry[:, :3]).sum(dim=1, keepdim=True)
            valid = valid & depth_ok & (dot > self.cfg.normal_threshold)
        return valid.to(reset.dtype) * (1.0 - reset)

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg = self.cfg
        samples, motion = buffers["samples"], buffers["motion"]
        # 1. Per-sample input (Isik21 3.1): L is the box-filtered (mean) linear radiance.
        radiance = torch.clamp(self._feature(samples, "color"), min=0.0).mean(dim=1)
        geometry = self._geometry(samples)

        # 2. Per-sample embedding, averaged over the samples (Isik21 eq. (1)).
        embedding = self.embedding(self._network_samples(samples))

        # 3. Warp the previous state (nearest neighbour), masked where it is invalid.
        # One Reproject per state tensor: no concatenated copy of the state to warp and split.
        inside = inside_previous_frame(motion)
        prev = {s.name: reproject(state[s.name], motion, nearest=1) for s in self.state_specs}
        valid = self._valid(inside, geometry, prev["geometry"], reset)
        keep = valid > 0.5  # `where`, not a product: a non-finite history cannot leak
        prev_embedding = torch.where(keep, prev["embedding"], embedding)
        prev_radiance = torch.where(keep, prev["radiance"], radiance)

        # 4. U-Net on [e_t, W e_{t-1}] -> kernel parameters (Isik21 eq. (2)).
        params = self.unet(torch.cat((embedding, prev_embedding), dim=1))
        k, d = cfg.kernels, cfg.feature_dim
        features = params[:, : k * d].split(d, dim=1)
        bandwidth = torch.square(params[:, k * d : k * d + k]).split(1, dim=1)  # a^k = x^2
        centre = torch.sigmoid(params[:, k * d + k : k * d + 2 * k]).split(1, dim=1)
        temporal_bandwidth = torch.square(params[:, -2:-1])  # b = x^2
        lam = torch.sigmoid(params[:, -1:])  # lambda

        # 5. Temporal accumulation of the embedding and the radiance (Isik21 eq. (3), (5)).
        acc_embedding = (1.0 - lam) * embedding + lam * prev_embedding
        acc_radiance = (1.0 - lam) * radiance + lam * prev_radiance

        # 6. K - 1 dilated spatial kernels (Isik21 eq. (4), (6)), dilation 2^(k-1).
        size = self.option_kernel_size
        filtered = acc_radiance
        for i in range(k - 1):
            filtered = affinity_filter(
                filtered, features[i], bandwidth[i], centre[i], size, dilation=2**i
            )

        # 7. The last spatial kernel and the temporal kernel, normalised jointly (eq. (7)-(8)).
        prev_features = torch.where(keep, prev["features"], features[-1])
        output = temporal_affinity_filter(
            filtered,
            features[-1],
            bandwidth[-1],
            centre[-1],
            prev["output"],
            prev_features,
            temporal_bandwidth,
            valid,
            size,
            self.option_temporal_size if cfg.temporal_size else size,
            dilation=2 ** (k - 1),
        )

        if self.training and torch.is_grad_enabled():  # for the regulariser, eq. (13)
            if bool(reset > 0.5):
                self._bandwidths.clear()
            reg = sum(torch.square(a).mean() for a in bandwidth)
            self._bandwidths.append(reg + torch.square(temporal_bandwidth).mean())
        if geometry is None:
            geometry = torch.zeros_like(state["geometry"])
        next_state = {
            "embedding": acc_embedding,
            "radiance": acc_radiance,
            "features": features[-1],
            "output": output,
            "geometry": geometry,
        }
        return output, next_state

    def loss(
        self, outputs: torch.Tensor, reference: torch.Tensor, temporal_weight: float
    ) -> torch.Tensor:
        """Isik21 eq. (9): SMAPE (eq. (10)-(11)) + temporal_weight x temporal SMAPE (eq. (12))
        + regulariser_weight x (sum_k E a_k^2 + E b^2) (eq. (13)) over the frames of the last
        unrolled clips (outputs, reference: (B, T, 3, H, W))."""
        eps = self.cfg.smape_eps
        loss = smape_l1(outputs, reference, eps)
        if temporal_weight and outputs.shape[1] > 1:
            d_out = outputs[:, 1:] - outputs[:, :-1]
            d_ref = reference[:, 1:] - reference[:, :-1]
            loss = loss + temporal_weight * smape_l1(d_out, d_ref, eps)
        regulariser = self.regulariser()
        return loss if regulariser is None else loss + regulariser

    def regulariser(self) -> torch.Tensor | None:
        """regulariser_weight x (sum_k E a_k^2 + E b^2) (Isik21 eq. (13)) over the frames
        unrolled since the last call (None outside training); what any `--loss` adds."""
        if not self._bandwidths:
            return None
        value = self.cfg.regulariser_weight * torch.stack(self._bandwidths).mean()
        self._bandwidths = []
        return value


def smape_l1(a: torch.Tensor, b: torch.Tensor, eps: float) -> torch.Tensor:
    """Isik21 eq. (11): (1/3) E_xyt ||a - b||_1 / (||a||_1 + ||b||_1 + eps), the L1 norms over
    the colour vector (dim -3 of (..., 3, H, W))."""
    num = (a - b).abs().sum(dim=-3)
    den = a.abs().sum(dim=-3) + b.abs().sum(dim=-3) + eps
    return (num / den).mean() / 3.0


__all__ = [
    "Affinity",
    "AffinityConfig",
    "Embedding",
    "UNet",
    "parameter_count",
    "smape_l1",
    "inside_previous_frame",
    "warp_nearest",
]
