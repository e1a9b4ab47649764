"""Temporal reprojection, history validity and accumulation (TA), for the exported graph.

One TA step is the custom op `TemporalAccumulation` (rtdenoise.ops.temporal_accumulation; the
models call `models.ops.temporal_accumulation.temporal_accumulation`), whose torch form is
`temporal_step` here: the warp is the op `Reproject` (bilinear, border-clamped:
rtdenoise.ops.reproject, `reproject` re-exported here), the rest plain tensor ops, no Python
branching on tensor values.

Conventions (docs/contract.md, "Buffers"): motion vectors are in pixels, x right, y down, and point
from the current pixel to its previous position: previous = current + motion. Pixel (x, y)
has its centre at integer coordinates; sampling is bilinear.

TA follows the reprojection-with-rejection scheme that Lee24 s.III-A adopts from Meng20,
Fan21 and Koskela19 (BMFR) (Lee24 refs. [2], [8], [17]; the classic Yang09 / SVGF
exponential moving average): reproject the previous accumulation, reject it where the
previous frame saw another surface (out of screen, depth or normal disagreement), then blend
with weight a = max(a_min, 1 / (history + 1)) so that the first frames average uniformly and
later frames converge to an exponential moving average with weight a_min (0.2 = Meng20's
history weight 0.8).

Four reprojections, `TemporalConfig.per_tap` (the op's attribute per_tap):
- 0, bilinear (`temporal_step`'s default; the models exported before per_tap): the whole
  previous state (accumulation, depth, normal) is warped bilinearly first and the
  *interpolated* depth and normal are tested, once per pixel. A deviation from SVGF and BMFR:
  at a silhouette the interpolated depth of a foreground pixel mixes background taps in (or
  rejects the pixel);
- 1, per tap (`per_tap_history`, SVGF: Schied17 s.4.1, BMFR): each of the four bilinear taps
  is tested on its own (inside the previous frame, the same relative-depth and normal-dot
  tests against the current pixel) and the bilinear weights are renormalised over the
  accepted taps; the history is dropped where they weigh less than 0.01 (SVGF's cut, so
  where no tap passes). Tap order, weights and the inside test follow crossreg's
  `models.reprojection.svgf_reproject`; the tests are TA's own (no fwidth, no 3 x 3 fallback,
  no erosion). docs/families/afn.md, wskp.md and nbg.md say which demo uses which;
- 2, per tap HDR-weighted (`per_tap_history(..., hdr=1)`, after Karis14, "High quality
  temporal supersampling", whose TAA resolve weighs each sample by 1 / (1 + luma)): the taps
  and tests of 1; in the average each accepted tap's weight is divided by 1 + its brightness
  above a bound, HDR_RATIO (4) x the darkest accepted tap's brightness + HDR_FLOOR (1)
  (brightness: the mean of the tap's C accumulated channels, at least 0); the 0.01 cut still
  reads the plain weights. Taps within the bound average as in 1 (noise, texture: no bias);
  a bright tap beside a dark one (a small light on a dark wall), which otherwise bleeds into
  the dark pixel at every sub-pixel warp, the bleed accumulating frame by frame, is weighed
  down by its excess. Measured on TA alone (benchmarks/history_bleed.py): at the committed
  sequence's strip the dark neighbours' history is 7-19 over frames 1-7 with per_tap 1 (the
  reference under 0.1), 0.3-3.6 with 2; Karis14's plain 1 / (1 + brightness) did as well
  there but darkened the validation sequences' history by 1-3.6 % (their 1-spp noise);
- 3, per tap HDR-weighted, squared (`per_tap_history(..., hdr=2)`): 2 with the weight divided
  by the square of 1 + the excess. Under 2 a bright tap's share of the average, w l / (1 + l -
  bound), tends to w as l grows: about one unit per sub-pixel warp still reaches a dark
  neighbour, and the model downstream sees the accumulated trail (nbg's strip failures,
  benchmarks/README.md "Where the strip's trail comes from"); under 3 it falls as 1 / l. TA alone
  on the committed strip: dark neighbours at most 0.75 over frames 0-7 against 0.3-3.6 with 2,
  relMSE lower on every sequence, the history's brightness within 1.1 % of 2's on the
  validation sequences and 4 % darker on the strip's (the bias 2 has at a light's own pixels,
  a little more of it).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from rtdenoise.ops.temporal_accumulation import HDR_FLOOR, HDR_RATIO

from .ops.reproject import reproject
from .reprojection import gather_pixels


@dataclass(frozen=True)
class TemporalConfig:
    """Thresholds of the history test and the accumulation weights."""

    depth_tolerance: float = 0.1  # valid if |d_prev - d| < depth_tolerance * d
    normal_threshold: float = 0.9  # valid if dot(n_prev, n) > normal_threshold
    min_alpha: float = 0.2  # a_min: weight of the current frame in the moving average
    max_history: float = 64.0  # history length is clamped (keeps the state bounded)
    per_tap: int = 0  # 0: test the bilinearly warped geometry; 1: test each tap (SVGF); 2: 1,
    # outlier-bright taps weighed down; 3: by the square (module docstring)


def in_bounds(motion: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) bool: the previous position lies inside the previous frame's pixels."""
    h, w = motion.shape[-2], motion.shape[-1]
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype).view(1, 1, w)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype).view(1, h, 1)
    px = xs + motion[:, 0]
    py = ys + motion[:, 1]
    inside = (px >= -0.5) & (px <= w - 0.5) & (py >= -0.5) & (py <= h - 0.5)
    return inside.unsqueeze(1)


def geometry_agrees(
    depth: torch.Tensor,
    normal: torch.Tensor,
    prev_depth: torch.Tensor,
    prev_normal: torch.Tensor,
    config: TemporalConfig,
) -> torch.Tensor:
    """(N, 1, H, W) bool: the previous geometry matches the current pixel's (relative depth
    within depth_tolerance, normal dot above normal_threshold; a zero normal never passes)."""
    depth_ok = (prev_depth - depth).abs() < config.depth_tolerance * depth.abs()
    normal_ok = (prev_normal * normal).sum(dim=1, keepdim=True) > config.normal_threshold
    return depth_ok & normal_ok


def history_validity(
    motion: torch.Tensor,
    depth: torch.Tensor,
    normal: torch.Tensor,
    prev_depth: torch.Tensor,
    prev_normal: torch.Tensor,
    reset: torch.Tensor,
    config: TemporalConfig = TemporalConfig(),
) -> torch.Tensor:
    """(N, 1, H, W) float in {0, 1}: where the reprojected history may be used.

    prev_depth / prev_normal are the previous frame's geometry already reprojected to the
    current pixels. Valid = in bounds & relative depth agreement & normal agreement & not
    reset. Pixels with a zero normal (background) never pass the normal test.
    """
    agree = geometry_agrees(depth, normal, prev_depth, prev_normal, config)
    valid = (in_bounds(motion) & agree).to(depth.dtype)
    return valid * (1.0 - reset)  # reset = 1 ignores the history, arithmetically


def accumulate(
    current: torch.Tensor,
    history: torch.Tensor,
    history_len: torch.Tensor,
    valid: torch.Tensor,
    config: TemporalConfig = TemporalConfig(),
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Blend `current` with the reprojected `history` (Yang09 / SVGF moving average).

    history_len: reprojected number of accumulated frames (N, 1, H, W); valid: (N, 1, H, W).
    Returns (accumulated, new history length, blend weight a). Where invalid, the history is
    dropped with `where` (not a multiply) so a non-finite history can never leak through.
    """
    ok = valid > 0.5
    n_prev = torch.where(ok, history_len, torch.zeros_like(history_len))
    hist = torch.where(ok, history, torch.zeros_like(history))
    alpha = torch.clamp(1.0 / (n_prev + 1.0), min=config.min_alpha)
    acc = alpha * current + (1.0 - alpha) * hist
    new_len = torch.clamp(n_prev + 1.0, max=config.max_history)
    return acc, new_len, alpha


def tap_brightness(values: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W): max(mean of the C channels of `values` (N, C, H, W), 0), summed in
    channel order (the fast kernels sum the same way, to the bit)."""
    total = values[:, :1]
    for c in range(1, values.shape[1]):
        total = total + values[:, c : c + 1]
    return torch.clamp(total / values.shape[1], min=0.0)


def outlier_bound(brightness: list[torch.Tensor], ok: list[torch.Tensor]) -> torch.Tensor:
    """(N, 1, H, W): HDR_RATIO x the darkest accepted tap's brightness + HDR_FLOOR (+inf where
    no tap is accepted), the darkest found by selects in tap order from +inf (a NaN tap is
    never the darkest; the fast kernels fold the same way)."""
    darkest = torch.full_like(brightness[0], float("inf"))
    for b, accepted in zip(brightness, ok, strict=True):
        darkest = torch.where(accepted & (b < darkest), b, darkest)
    return HDR_RATIO * darkest + HDR_FLOOR


def per_tap_history(
    motion: torch.Tensor,
    depth: torch.Tensor,
    normal: torch.Tensor,
    ta_state: torch.Tensor,
    geometry_state: torch.Tensor,
    reset: torch.Tensor,
    config: TemporalConfig = TemporalConfig(),
    hdr: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """SVGF's per-tap reprojection of `ta_state` (N, C + 1, H, W): (warped ta_state, valid
    (N, 1, H, W) in {0, 1}). Each bilinear tap around current + motion passes if it lies in
    the previous frame and its depth and normal agree with the current pixel's (the tests of
    `history_validity`); the accepted taps' bilinear weights are renormalised; valid where
    they sum to at least 0.01 and reset is 0. A rejected tap's value is selected away, never
    multiplied by 0; where invalid the warped state is 0. hdr 1 or 2 (per_tap 2 or 3, module
    docstring): the accepted taps are averaged with weights w / (1 + max(brightness - bound,
    0))^hdr (the square a product), the bound from the darkest accepted tap
    (`outlier_bound`); the cut on the plain w."""
    n, c1, h, w = ta_state.shape
    flat = torch.cat((ta_state, geometry_state), dim=1).flatten(2)
    xs = torch.arange(w, device=motion.device, dtype=motion.dtype).view(1, 1, w)
    ys = torch.arange(h, device=motion.device, dtype=motion.dtype).view(1, h, 1)
    px, py = xs + motion[:, 0], ys + motion[:, 1]
    x0, y0 = torch.floor(px), torch.floor(py)
    ax, ay = (px - x0).unsqueeze(1), (py - y0).unsqueeze(1)
    ex, ey = 1.0 - ax, 1.0 - ay
    taps = []  # (weight, gathered values, ok) in the order nw, ne, sw, se
    for ox, oy, weight in ((0, 0, ex * ey), (1, 0, ax * ey), (0, 1, ex * ay), (1, 1, ax * ay)):
        fx, fy = x0 + ox, y0 + oy
        g = gather_pixels(flat, fx.long(), fy.long(), w)
        inside = ((fx >= 0) & (fx <= w - 1) & (fy >= 0) & (fy <= h - 1)).unsqueeze(1)
        prev_normal, prev_depth = g[:, c1 : c1 + 3], g[:, c1 + 3 : c1 + 4]
        ok = inside & geometry_agrees(depth, normal, prev_depth, prev_normal, config)
        taps.append((torch.where(ok, weight, torch.zeros_like(weight)), g, ok))
    if hdr:
        brightness = [tap_brightness(g[:, : c1 - 1]) for _, g, _ in taps]
        bound = outlier_bound(brightness, [ok for _, _, ok in taps])
    acc = torch.zeros_like(ta_state)
    total = torch.zeros_like(depth)  # the accepted taps' bilinear weight: the 0.01 cut
    weighed = torch.zeros_like(depth)  # their averaging weight (= total unless hdr)
    for t, (weight, g, ok) in enumerate(taps):
        average_weight = weight
        if hdr:  # weighed down by the brightness above the bound (selected: a rejected tap's
            # value, maybe non-finite, never enters)
            excess = torch.clamp(brightness[t] - bound, min=0.0)
            scale = 1.0 + excess
            if hdr == 2:
                scale = scale * scale
            average_weight = torch.where(ok, weight / scale, torch.zeros_like(weight))
        acc = acc + average_weight * torch.where(ok, g[:, :c1], torch.zeros_like(g[:, :c1]))
        total = total + weight
        weighed = weighed + average_weight
    accepted = total >= 0.01
    warped = acc / torch.where(accepted, weighed, torch.ones_like(weighed))
    valid = accepted.to(depth.dtype) * (1.0 - reset)  # reset = 1 ignores the history
    return torch.where(valid > 0.5, warped, torch.zeros_like(warped)), valid


def temporal_step(
    current: torch.Tensor,
    motion: torch.Tensor,
    depth: torch.Tensor,
    normal: torch.Tensor,
    ta_state: torch.Tensor,
    geometry_state: torch.Tensor,
    reset: torch.Tensor,
    config: TemporalConfig = TemporalConfig(),
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One TA step on C-channel `current` (N, C, H, W): the torch form of the op
    TemporalAccumulation (`models.ops.temporal_accumulation.temporal_accumulation`, what the
    models call; the config's numbers may be 0-d tensors).

    ta_state: (N, C + 1, H, W) previous accumulation and its history length;
    geometry_state: (N, 4, H, W) previous normal (3) and depth (1).
    Returns (accumulated (N, C, H, W), blend weight a (N, 1, H, W), next ta_state,
    next geometry_state). config.per_tap (a Python int) picks the reprojection (module
    docstring): 0 warps the whole state and tests it once per pixel, 1 tests each tap, 2 tests
    each tap and weighs the accepted ones by brightness, 3 by its square.
    """
    c = current.shape[1]
    if config.per_tap:
        hdr = max(config.per_tap - 1, 0)  # per_tap 2, 3: the HDR weight's power
        warped, valid = per_tap_history(
            motion, depth, normal, ta_state, geometry_state, reset, config, hdr
        )
    else:
        warped = reproject(torch.cat((ta_state, geometry_state), dim=1), motion)
        prev_normal, prev_depth = warped[:, c + 1 : c + 4], warped[:, c + 4 : c + 5]
        valid = history_validity(motion, depth, normal, prev_depth, prev_normal, reset, config)
    history, history_len = warped[:, :c], warped[:, c : c + 1]
    acc, new_len, alpha = accumulate(current, history, history_len, valid, config)
    next_ta = torch.cat((acc, new_len), dim=1)
    next_geometry = torch.cat((normal, depth), dim=1)
    return acc, alpha, next_ta, next_geometry
