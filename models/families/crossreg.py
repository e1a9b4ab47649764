"""Cross-regression online denoiser (Choi24): it learns while it runs, from the frames alone.

`CrossReg.forward` is one frame of Choi24 Fig. 3, learning included:

1. log transform (s.4.4): y^A = log1p(color), y^B = log1p(color_b), two independent estimates
   (`log_scale` k: k log1p(x / k), an option; 1 = the paper);
2. cross-regression (s.4.1, eqs. (4)-(7); op `CrossRegression`): pilots f~^A (y^B fitted on
   A's variables) and f~^B, kept within the window's observed range;
3. reprojection (SVGF taps, `models.reprojection`) of the previous log output and pilots;
4. U-Net (s.4.4) on [f~^A, f~^B, R f^p, albedo, normal] -> per-pixel bandwidths
   band_k = 1 / (x_k^2 + 1e-4) for colour A, colour B, albedo, normal, position, and
   alpha = sigmoid(x_6), with weights theta_{t-1} read from the state;
5. spatial cross-bilateral filter (eq. (9); op `CrossBilateralFilter`) and temporal blend with
   the reprojected output (eqs. (8), (10)): f^A, f^B and the displayed f;
6. self-supervised loss (eqs. (11)-(13)) against the other buffer's pilot and the warped previous
   pilots; one gradient step (`torch.autograd.grad` through the U-Net and the filter's
   registered backward) and one Adam step -> theta_t, the next state;
7. output = max(expm1(f), 0);
8. (an option, not in the paper; the demo has it) a gain curve over the output's brightness,
   fitted online to the mean of the two noisy buffers (`models.gain_curve`), scales the output:
   it undoes the log domain's darkening, which no theta can.

The forward pass of step 4 is the one displayed and the one back-propagated (it uses
theta_{t-1}); no gradient crosses frames. The state carries the history (log output and both
pilots), the geometry (normal, depth) and the learning: theta, Adam's m and v, the step count t
(and the gain curve's sums), the frame's loss (output only) and two host-set controls, read even
when reset = 1: `freeze` (1 skips this frame's update) and `keep` (1: a reset keeps theta, m, v,
t and the curve). Reset (first frame, camera cut) restarts the history; without `keep` (a zero
state, as a host that knows nothing of it leaves it) also the learning, from theta at
initialisation (the module's parameters: Glorot-uniform, seeded, or pretrained), m = v = t = 0
and an empty curve (gain 1).

Pretraining (an option beyond the paper, which starts from the random init): `denoise-train
--family crossreg` trains the initial theta offline, supervised, with the online update frozen
(`training_state`: freeze = 1 on every frame of the outer loop's clips), so theta is the U-Net's
parameters on every frame and the family default loss (SMAPE + temporal_weight x temporal
SMAPE against the reference) reaches them through each frame's output and, via the carried
history (kept attached in that mode only), through the temporal blend. The checkpoint holds the
trained U-Net; a reset without `keep` (every first frame) takes theta from it, so its export
runs the same online-learning graph from the pretrained init.

Choices (all in `CrossRegConfig`, stored in checkpoints), from the official code
(CGLab-GIST/cross-denoiser) where the paper's text is loose:
- regression: window 17, centres every 4th pixel, P = 6 variables per colour channel, ridge
  1e-3, weight floor 1e-7 (see rtdenoise.ops.cross_regression);
- filter: window 11, eq. (9) with one exp and band_p on the pixel distance / r^2 (the paper's
  typos); alpha' = valid alpha + (1 - valid): no history -> spatial only;
- U-Net: the official layout, widths 8/16/32: two 3x3 conv + ReLU per level, 2x2 max-pool down,
  1x1 stride-2 transposed conv up (no activation), skip concatenation, one 3x3 conv at the top
  decoder level, a 1x1 head to 6 outputs (31,414 parameters); Glorot-uniform weights, zero
  biases (Keras defaults), seeded by `seed`;
- U-Net input where the history is invalid: the mean of the two pilots (the official temporal
  screening's fallback), not 0;
- loss elementwise per colour channel (the code) with eps 1e-2; the temporal term pairs each
  output with the other buffer's warped pilot (`temporal_pairing` "cross", eq. (13); "same" is
  the official code); it is masked by the history validity: where no history, the pixel's loss
  is the spatial term alone;
- Adam lr 1e-3, betas 0.9 / 0.999, eps 1e-7 in Kingma & Ba's Algorithm 1 form (= torch.optim.Adam;
  the official Keras Adam adds eps to the uncorrected sqrt(v));
- pilots clamped to the largest log value of either buffer over the regression window
  (`pilot_range_clamp`, not in the paper): where the regression variable dy / (sigma_c +
  sigma_q + 1e-2) meets noise-free regions (emitters, a constant background: sigma = 0) eq. (5)
  extrapolates (log values of 45 where the inputs reach 2.85 were measured at an emitter's
  edge); the official code masks emissive and environment pixels out instead, which the
  contract's buffers cannot tell;
- reprojection: SVGF thresholds 10 (depth) and 4 (normal) over screen-space derivatives computed
  from the depth and normal buffers, 3x3 fallback, 3x3 erosion (of the mask of both the blend
  and the labels); the code's emissive/environment mask is left out, and its temporal screening
  (7x7 min/max overlap test) is an option off by default (`temporal_screening` = 7 screens
  the loss's temporal labels);
- H and W must be multiples of 2 ** (len(widths) - 1) (the max-pools).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
import torch.nn.functional as F
from torch import nn

from ..base import DenoiserModel, FamilyConfig, StateSpec, register_family
from ..gain_curve import GainCurve
from ..online import Adam, ParameterLayout, adam_step, traced_step
from ..ops.cross_bilateral_filter import cross_bilateral_filter
from ..ops.cross_regression import cross_regression
from ..ops.export_mode import use_custom_op
from ..profiling import stage
from ..reprojection import ReprojectionConfig, svgf_reproject_geometry

INPUTS = ("color", "color_b", "albedo", "normal", "depth", "motion")
NOTE = (
    "pass two independent estimates of the frame's linear HDR radiance (color, color_b: e.g. the "
    "samples split in two halves), albedo, normal in [-1, 1], linear view depth and motion in "
    "pixels (previous = current + motion); do NOT tonemap, demodulate or accumulate: the graph "
    "does it, and learns its weights from these frames (state theta, adam_*)"
)
BAND_EPS = 1e-4  # band = 1 / (x^2 + 1e-4), official code
FILTER_EPS = 1e-4  # S / (W + 1e-4), official code


@dataclass(frozen=True)
class CrossRegConfig(FamilyConfig):
    """Choi24's constants and the open choices (see the module docstring)."""

    family = "crossreg"

    regression_window: int = 17
    regression_stride: int = 4
    filter_window: int = 11
    widths: tuple[int, ...] = (8, 16, 32)
    seed: int = 0  # Glorot initialisation of the U-Net
    lr: float = 1e-3
    beta1: float = 0.9
    beta2: float = 0.999
    adam_eps: float = 1e-7
    loss_eps: float = 1e-2
    temporal_pairing: str = "cross"  # "cross" (eq. (13)) or "same" (official code)
    depth_threshold: float = 10.0
    normal_threshold: float = 4.0
    reprojection_fallback: bool = True
    pilot_range_clamp: bool = True  # pilots <= max of both inputs over the regression window
    # temporal screening of the loss's labels (official code, off in the paper's text): a warped
    # previous pilot is a label only where its k x k min / max range overlaps the current
    # pilots' (every channel); 0 = off, else the odd window k (the code's 7)
    temporal_screening: int = 0
    # eq. (11)'s weight of the temporal term (the paper's 0.5); 0 = the spatial term alone. The
    # temporal labels (warped previous pilots) share noise with the warped previous output that
    # each buffer's output blends in, so that term also rewards leaning on the history
    temporal_loss_weight: float = 0.5
    # a floor on the temporal weight alpha (not in the paper: 0): with alpha near 0 the output is
    # the reprojected history and a wrong one (a light behind moving glass) is never cleared
    alpha_min: float = 0.0
    # the warped previous log output kept within [min(f~A, f~B) - d, max(f~A, f~B) + d] of this
    # frame's pilots, d this value (not in the paper: 0 = off): the geometry tests pass an edge
    # pixel whose depth sample missed a light its colour partly holds, and its history then
    # lights the dark pixel it lands on
    history_clamp: float = 0.0
    # the scale k of the log transform y = k log1p(x / k) the regression and the filter run on
    # (Choi24 s.4.4: k = 1). The mean of log values lies below the log of the mean where a pixel
    # is noisy (Jensen), so the output is darker than the reference, most in dim noisy scenes (a
    # third darker on validation/long_000 at k = 1), and no theta can undo it; a larger k keeps
    # radiance below k nearly linear (unbiased: the pilots regress the other buffer's samples,
    # the idea of cross-regression) and still compresses lights far above it. The U-Net sees
    # log1p of the radiance whatever k, and history_clamp stays in those log units
    log_scale: float = 1.0
    # an online gain curve over the output's brightness, learned from the noisy radiance (an
    # unbiased label) and applied to the output (models/gain_curve.py; not in the paper: 0 = off,
    # else its nodes K): it undoes the log domain's darkening that no theta can, while the
    # history and the loss stay Choi24's. Its statistics are a learned state like theta
    gain_curve_bins: int = 0
    gain_curve_range: float = GainCurve.range
    gain_curve_decay: float = GainCurve.decay
    gain_curve_eps: float = GainCurve.eps
    gain_curve_prior: float = GainCurve.prior
    gain_curve_blur: int = GainCurve.blur
    gain_curve_limit: float = GainCurve.limit

    def validate(self) -> None:
        w, s = self.regression_window, self.regression_stride
        if w < 3 or w % 2 == 0 or not 1 <= s <= w // 2 + 1:
            raise self.fail(
                "needs an odd regression_window >= 3 and 1 <= regression_stride <= "
                f"regression_window // 2 + 1, got {w}, {s}"
            )
        if self.filter_window < 3 or self.filter_window % 2 == 0:
            raise self.fail(f"filter_window must be odd >= 3, got {self.filter_window}")
        if len(self.widths) < 2 or any(x < 1 for x in self.widths):
            raise self.fail(f"widths must list >= 2 positive sizes, got {self.widths}")
        k = self.temporal_screening
        if k != 0 and (k < 3 or k % 2 == 0):
            raise self.fail(f"temporal_screening must be 0 or odd >= 3, got {k}")
        if not 0.0 <= self.alpha_min < 1.0:
            raise self.fail(f"alpha_min must be in [0, 1), got {self.alpha_min}")
        if not 0.0 < self.log_scale <= 1e6:
            raise self.fail(f"log_scale must be in (0, 1e6], got {self.log_scale}")
        if self.gain_curve_bins and (
            self.gain_curve_bins < 2
            or self.gain_curve_range <= 0
            or not 0 <= self.gain_curve_decay < 1
            or self.gain_curve_eps <= 0
            or self.gain_curve_prior <= 0
            or self.gain_curve_blur < 0
            or self.gain_curve_limit < 1
        ):
            raise self.fail(
                "gain_curve needs bins 0 (off) or >= 2, range > 0, decay in [0, 1), eps > 0, "
                f"prior > 0, blur >= 0 and limit >= 1, got {self.gain_curve_bins}, "
                f"{self.gain_curve_range}, {self.gain_curve_decay}, {self.gain_curve_eps}, "
                f"{self.gain_curve_prior}, {self.gain_curve_blur}, {self.gain_curve_limit}"
            )
        if self.history_clamp < 0.0:
            raise self.fail(f"history_clamp must be >= 0 (0 = off), got {self.history_clamp}")
        if not 0.0 <= self.temporal_loss_weight <= 1.0:
            raise self.fail(
                f"temporal_loss_weight must be in [0, 1], got {self.temporal_loss_weight}"
            )
        if self.temporal_pairing not in ("cross", "same"):
            raise self.fail(
                f"temporal_pairing must be 'cross' or 'same', got {self.temporal_pairing!r}"
            )
        if self.lr <= 0 or not 0 <= self.beta1 < 1 or not 0 <= self.beta2 < 1:
            raise self.fail(
                f"needs lr > 0 and betas in [0, 1), got {self.lr}, {self.beta1}, {self.beta2}"
            )


def screened(
    pilot_a: torch.Tensor,
    pilot_b: torch.Tensor,
    prev_a: torch.Tensor,
    prev_b: torch.Tensor,
    window: int,
) -> torch.Tensor:
    """(N, 1, H, W) bool: the warped previous pilots' window x window range (min / max over both
    buffers) overlaps the current pilots' in every channel (the official code's temporal
    screening of the labels)."""
    r = window // 2

    def span(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lo = -F.max_pool2d(-torch.minimum(a, b), window, 1, r)
        return lo, F.max_pool2d(torch.maximum(a, b), window, 1, r)

    (cur_lo, cur_hi), (prev_lo, prev_hi) = span(pilot_a, pilot_b), span(prev_a, prev_b)
    overlap = (prev_hi >= cur_lo) & (prev_lo <= cur_hi)
    return overlap.all(dim=1, keepdim=True)


class UNet(nn.Module):
    """Choi24 s.4.4, official layout: (conv3x3 + ReLU) x 2 per encoder level with 2x2 max-pool
    down; per decoder level a 1x1 stride-2 transposed conv up (no activation), concatenation
    with the skip, (conv3x3 + ReLU) x 2 (x 1 at the top level); 1x1 head."""

    def __init__(self, in_channels: int, widths: tuple[int, ...], out_channels: int) -> None:
        super().__init__()

        def block(c_in: int, c_out: int, convs: int) -> nn.Sequential:
            layers: list[nn.Module] = []
            for i in range(convs):
                layers += [nn.Conv2d(c_in if i == 0 else c_out, c_out, 3, padding=1), nn.ReLU()]
            return nn.Sequential(*layers)

        self.encoders = nn.ModuleList()
        c = in_channels
        for w in widths:
            self.encoders.append(block(c, w, 2))
            c = w
        self.ups = nn.ModuleList()
        self.decoders = nn.ModuleList()
        for level in range(len(widths) - 2, -1, -1):  # decoder levels, coarse to fine
            c_up = widths[level + 1]
            self.ups.append(nn.ConvTranspose2d(c_up, c_up, 1, stride=2, output_padding=1))
            self.decoders.append(block(c_up + widths[level], widths[level], 2 if level else 1))
        self.head = nn.Conv2d(widths[0], out_channels, 1)

    def reset_parameters(self, seed: int) -> None:
        """Glorot-uniform weights, zero biases (Keras defaults), from `seed`."""
        gen = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            for module in self.modules():
                if isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
                    fan_in = module.weight.shape[1] * module.weight[0, 0].numel()
                    fan_out = module.weight.shape[0] * module.weight[0, 0].numel()
                    bound = (6.0 / (fan_in + fan_out)) ** 0.5
                    module.weight.copy_(
                        (torch.rand(module.weight.shape, generator=gen) * 2.0 - 1.0) * bound
                    )
                    module.bias.zero_()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for level, encoder in enumerate(self.encoders):
            if level > 0:
                x = F.max_pool2d(x, 2)
            x = encoder(x)
            skips.append(x)
        for i, (up, decoder) in enumerate(zip(self.ups, self.decoders, strict=True)):
            x = decoder(torch.cat((up(x), skips[len(skips) - 2 - i]), dim=1))
        return self.head(x)


@register_family
class CrossReg(DenoiserModel):
    """Choi24 online cross-regression denoiser (see the module docstring)."""

    family = "crossreg"
    config_class = CrossRegConfig
    example_config = {"widths": [4, 8, 16], "regression_window": 9, "filter_window": 5}
    inputs = INPUTS
    input_note = NOTE

    def __init__(self, config: CrossRegConfig | dict | None = None) -> None:
        super().__init__()
        self.cfg = config = CrossRegConfig.of(config)
        self.pad_multiple = 2 ** (len(config.widths) - 1)
        # [f~A, f~B, R f^p, albedo, normal] -> 5 bandwidths + alpha
        self.unet = UNet(15, tuple(config.widths), 6)
        self.unet.reset_parameters(config.seed)
        self.layout = ParameterLayout.of(self.unet)
        self.adam = Adam(config.lr, config.beta1, config.beta2, config.adam_eps)
        self.reprojection = ReprojectionConfig(
            config.depth_threshold, config.normal_threshold, config.reprojection_fallback
        )
        p, one = self.layout.size, (1, 1)
        self.state_specs = (
            StateSpec("history", 9),  # log output, pilot A, pilot B
            StateSpec("geometry", 4),  # normal, depth
            StateSpec("theta", p, size=one),  # U-Net weights theta_t (layout: rtdenoise.online)
            StateSpec("adam_m", p, size=one),
            StateSpec("adam_v", p, size=one),
            StateSpec("adam_t", 1, size=one),  # steps taken
            StateSpec("loss", 1, size=one),  # this frame's loss (output only)
            StateSpec("freeze", 1, size=one),  # host control: 1 = no update this frame
            StateSpec("keep", 1, size=one),  # host control: 1 = a reset keeps theta and Adam's
        )
        self.gain_curve = None
        if config.gain_curve_bins:  # its statistics: sum w out y, sum w out^2 per node
            self.gain_curve = GainCurve(
                **{f.name: getattr(config, f"gain_curve_{f.name}") for f in fields(GainCurve)}
            )
            self.state_specs += (StateSpec("gain_curve", 2 * config.gain_curve_bins, size=one),)

    # -- the contract ----------------------------------------------------------------------

    def online_spec(self) -> dict:
        """The `rtdenoise.online` metadata: what is learned, how, and where it lives."""
        return {
            "method": "Choi24 self-supervised cross-regression loss, one Adam step per frame",
            "optimizer": "adam",
            "lr": self.adam.lr,
            "beta1": self.adam.beta1,
            "beta2": self.adam.beta2,
            "eps": self.adam.eps,
            "parameters": "theta",
            "moments": ["adam_m", "adam_v"],
            "step": "adam_t",
            "loss": "loss",
            "freeze": "freeze",
            "keep": "keep",
            "controls": ["freeze", "keep"],
            "layout": self.layout.to_json(),
            "statistics": ["gain_curve"] if self.gain_curve else [],
        }

    def declaration(self):
        declared = super().declaration()
        return type(declared)(**{**declared.__dict__, "online": self.online_spec()})

    def export_module(self, contract_module: nn.Module, example_args: tuple) -> nn.Module:
        """torch.export cannot trace autograd.grad: trace the whole step with make_fx first."""
        return traced_step(contract_module, example_args)

    def training_state(self, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Offline pretraining of the initial theta (`denoise-train --family crossreg`): every
        clip of the outer loop runs with `freeze` = 1, so theta is the module's parameters on
        every frame (the graph kept: see `_frame`) and the supervised loss (the default,
        SMAPE + temporal SMAPE) reaches them through each frame's output."""
        return {**state, "freeze": torch.ones_like(state["freeze"])}

    # -- one frame --------------------------------------------------------------------------

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        n = buffers["color"].shape[0]
        if n == 1:
            return self._frame(buffers, state, reset)
        # One learner per sequence of the batch (each has its own theta in the state).
        outs = [
            self._frame(
                {k: v[i : i + 1] for k, v in buffers.items()},
                {k: v[i : i + 1] for k, v in state.items()},
                reset,
            )
            for i in range(n)
        ]
        output = torch.cat([o for o, _ in outs])
        return output, {k: torch.cat([s[k] for _, s in outs]) for k in state}

    def _frame(
        self, buffers: dict[str, torch.Tensor], state: dict[str, torch.Tensor], reset: torch.Tensor
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        cfg = self.cfg
        fresh = reset > 0.5
        color = torch.clamp(buffers["color"], min=0.0)
        color_b = torch.clamp(buffers["color_b"], min=0.0)
        albedo = torch.clamp(buffers["albedo"], min=0.0)
        normal, motion = buffers["normal"], buffers["motion"]
        depth = torch.clamp(buffers["depth"], min=0.0)

        # 1-2. Log transform (Choi24 s.4.4, scale k = `log_scale`) and cross-regression pilots
        # (s.4.1).
        k = cfg.log_scale
        scaled = k != 1.0

        def from_linear(x: torch.Tensor) -> torch.Tensor:  # x -> y = k log1p(x / k)
            return k * torch.log1p(x / k) if scaled else torch.log1p(x)

        def to_linear(y: torch.Tensor) -> torch.Tensor:
            return k * torch.expm1(y / k) if scaled else torch.expm1(y)

        def to_log(y: torch.Tensor) -> torch.Tensor:  # y as log1p(x), the U-Net's units
            return torch.log1p(to_linear(y)) if scaled else y

        with stage("regression"):
            y_a, y_b = from_linear(color), from_linear(color_b)
            pilot_a, pilot_b = cross_regression(
                y_a, y_b, albedo, normal, cfg.regression_window, cfg.regression_stride
            )
            if cfg.pilot_range_clamp:  # no extrapolation beyond the window's observed values
                r = cfg.regression_window // 2
                hi = F.max_pool2d(torch.maximum(y_a, y_b), cfg.regression_window, 1, r)
                pilot_a, pilot_b = torch.minimum(pilot_a, hi), torch.minimum(pilot_b, hi)

        # 3. Reprojection of the previous log output and pilots (SVGF taps).
        history = torch.where(fresh, 0.0, state["history"])
        geometry = torch.where(fresh, 0.0, state["geometry"])
        with stage("reprojection"):
            warped, valid = svgf_reproject_geometry(
                history, geometry, motion, normal, depth, self.reprojection
            )
        valid = valid * (1.0 - reset)
        has_history = valid > 0.5
        prev_out = torch.where(has_history, warped[:, :3], 0.5 * (pilot_a + pilot_b))
        # the U-Net's units, log1p of the radiance (the same tensors when log_scale is 1)
        log_a, log_b, log_prev = to_log(pilot_a), to_log(pilot_b), to_log(prev_out)
        if cfg.history_clamp:  # the history no farther than d (log units) from the pilots
            d = cfg.history_clamp
            lo, hi = torch.minimum(log_a, log_b) - d, torch.maximum(log_a, log_b) + d
            log_prev = torch.minimum(torch.maximum(log_prev, lo), hi)
            prev_out = from_linear(torch.expm1(log_prev)) if scaled else log_prev
        prev_a, prev_b = warped[:, 3:6], warped[:, 6:9]
        labelled = has_history  # where the warped previous pilots are the temporal labels
        if cfg.temporal_screening:
            labelled = labelled & screened(pilot_a, pilot_b, prev_a, prev_b, cfg.temporal_screening)

        # theta_{t-1}: the state, or the initialisation after a reset that does not keep it
        # (`keep`, a host control: a camera cut restarts the history, not the learning).
        relearn = fresh & (state["keep"].reshape(-1)[:1] < 0.5)
        theta = torch.where(relearn, self.layout.flatten(self.unet), state["theta"].reshape(-1))
        # Attached to the module's parameters: the outer (offline) training only, under grad
        # mode. Then theta_t keeps its graph through the Adam gate: frozen (`training_state`),
        # theta is the parameters on every frame of the clip; the history keeps its graph too.
        attached = theta.requires_grad
        # frozen outer training: no online gradient to take (the gate would drop it). Never
        # while exporting: the trace (symbolic, models/online.py traced_step) sees the weights as
        # attached too, and freeze is a graph input there, not a value to branch on (the export
        # puts the backward under an If on it instead, export/learning_branch.py)
        skip_grad = attached and not use_custom_op() and bool(state["freeze"].reshape(-1)[0] > 0.5)
        with torch.enable_grad():
            if not attached:
                theta = theta.detach().requires_grad_(True)

            # 4. U-Net: bandwidths and temporal weight (s.4.2, s.4.4).
            with stage("unet"):
                net_in = torch.cat((log_a, log_b, log_prev, albedo, normal), dim=1)
                params = self.layout.unflatten(theta)
                raw = torch.func.functional_call(self.unet, params, (net_in,))
                band = 1.0 / (raw[:, :5] ** 2 + BAND_EPS)
                alpha = torch.sigmoid(raw[:, 5:6])
                if cfg.alpha_min:  # at least alpha_min of this frame's filtered pilots
                    alpha = cfg.alpha_min + (1.0 - cfg.alpha_min) * alpha

            # 5. Spatial filter (eq. (9)) and temporal blend (eqs. (8), (10)).
            with stage("filter"):
                sum_a, sum_b, _, _ = cross_bilateral_filter(
                    pilot_a, pilot_b, albedo, normal, band, cfg.filter_window
                )
            alpha = valid * alpha + (1.0 - valid)
            hat_a = alpha * sum_a[:, :3] / (sum_a[:, 3:] + FILTER_EPS) + (1 - alpha) * prev_out
            hat_b = alpha * sum_b[:, :3] / (sum_b[:, 3:] + FILTER_EPS) + (1 - alpha) * prev_out
            both = (sum_a[:, :3] + sum_b[:, :3]) / (sum_a[:, 3:] + sum_b[:, 3:] + FILTER_EPS)
            hat = alpha * both + (1 - alpha) * prev_out

            # 6. Self-supervised loss (eqs. (11)-(13)) and its gradient.
            loss = self.online_loss(hat_a, hat_b, pilot_a, pilot_b, prev_a, prev_b, labelled)
            if skip_grad:
                grad = torch.zeros_like(theta).detach()
            else:
                with stage("backward"):
                    (grad,) = torch.autograd.grad(loss, theta, retain_graph=attached)

        # one gate for every learned state (export/learning_branch.py puts theta's update under
        # an If on it; the gain curve's sums stay in the main graph, where the output reads them)
        learn = 1.0 - torch.clamp(state["freeze"].reshape(-1)[:1], 0.0, 1.0) > 0.5
        with stage("adam"):
            theta_next, m, v, t = adam_step(
                theta if attached else theta.detach(),
                grad,
                torch.where(relearn, 0.0, state["adam_m"].reshape(-1)),
                torch.where(relearn, 0.0, state["adam_v"].reshape(-1)),
                torch.where(relearn, 0.0, state["adam_t"].reshape(-1)),
                learn,
                self.adam,
            )

        # 7. Back to linear radiance.
        output = torch.clamp(to_linear(hat), min=0.0)
        if not attached:
            output = output.detach()
        as_state = {"theta": theta_next, "adam_m": m, "adam_v": v, "adam_t": t}
        if self.gain_curve:  # 8. the gain curve (not in the paper), this frame's pixels included
            with stage("gain curve"):
                stats = torch.where(relearn, 0.0, state["gain_curve"].reshape(1, -1))
                label = 0.5 * (color + color_b)  # unbiased: its mean is the reference
                now = self.gain_curve.statistics(output.detach(), label)
                stats = torch.where(learn, self.gain_curve.decay * stats + now, stats)
                output = self.gain_curve.apply(output, stats)
            as_state["gain_curve"] = stats
        next_state = {k: x.reshape(1, -1, 1, 1) for k, x in as_state.items()}
        history = torch.cat((hat, pilot_a, pilot_b), dim=1)
        next_state.update(
            history=history if attached else history.detach(),
            geometry=torch.cat((normal, depth), dim=1),
            loss=loss.detach().reshape(1, 1, 1, 1),
            freeze=state["freeze"],
            keep=state["keep"],
        )
        return output, next_state

    def online_loss(
        self,
        hat_a: torch.Tensor,
        hat_b: torch.Tensor,
        pilot_a: torch.Tensor,
        pilot_b: torch.Tensor,
        prev_a: torch.Tensor,
        prev_b: torch.Tensor,
        has_history: torch.Tensor,
    ) -> torch.Tensor:
        """Choi24 eqs. (11)-(13), elementwise: each buffer's output against the other buffer's
        pilot (spatial) and against a warped previous pilot (temporal, where there is one)."""
        eps = self.cfg.loss_eps

        def rel(x: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
            return (x - label) ** 2 / (label * label + eps)

        spatial = 0.5 * (rel(hat_a, pilot_b) + rel(hat_b, pilot_a))  # eq. (12)
        label_a, label_b = (
            (prev_b, prev_a)
            if self.cfg.temporal_pairing == "cross"
            else (
                prev_a,
                prev_b,
            )
        )
        temporal = 0.5 * (rel(hat_a, label_a) + rel(hat_b, label_b))  # eq. (13)
        temporal = torch.where(has_history, temporal, spatial)
        w = self.cfg.temporal_loss_weight
        return ((1.0 - w) * spatial + w * temporal).mean()  # eq. (11): w = 0.5


__all__ = ["CrossReg", "CrossRegConfig", "UNet"]
