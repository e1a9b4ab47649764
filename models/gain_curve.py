"""An online gain curve learned from unbiased labels: what undoes a log-domain denoiser's
darkening (an addition to Choi24, `CrossRegConfig.gain_curve_bins`).

Choi24 regresses and filters log1p values (s.4.4); the mean of log values lies below the log of
the mean where a pixel is noisy (Jensen), so the output is darker than the reference where the
input is noisy and dim (a third darker on validation/long_000), and its online loss, in log
values too, has labels biased the same way. The noisy radiance itself is unbiased: the mean of
the two buffers has the reference as its expectation. So a gain g fitted online by weighted
least squares, g = sum w out y / sum w out^2 over pixels and frames (w = 1 / (out^2 + eps),
relative), has the right brightness as its target whatever the noise.

One gain for a whole frame brightens lights that are already right; one per screen tile mixes
unlike pixels and does not follow the camera. The gain here is a curve over the output's
brightness u = log1p(mean over channels of out): K nodes spread over u in [0, range], each
pixel's statistics split between its two nearest nodes (linear hat weights) and the curve read
back the same way, so dark noisy pixels and lights each get their own gain, learned from every
pixel of their brightness. A pixel is binned by its neighbourhood's brightness, not its own
(`guide`). The statistics are discounted sums over frames (weight `decay` on the past), a
learned state of 2 K values that a camera cut keeps and a frame-size change does not touch;
`prior` pixel-weights of gain 1 hold a node few pixels reached near 1, and `limit` bounds every
gain: a node of the output's brightness holds both a light the log domain darkened (a thin
emitter's pixels, whose label is far brighter) and the dark pixels the filter lit beside it,
which the same gain would light further.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F


@dataclass(frozen=True)
class GainCurve:
    """The curve's constants (see the module docstring)."""

    bins: int = 32
    range: float = 4.0  # u = log1p(brightness) covered by the nodes; brighter reads the last
    decay: float = 0.8  # weight of the past statistics per frame
    eps: float = 1e-3  # w = 1 / (out^2 + eps)
    prior: float = 64.0  # pixel-weights of gain 1 in every node
    blur: int = 1  # the statistics binned by the brightness of (2 blur + 1)^2 pixels
    limit: float = 1.5  # gains within [1 / limit, limit]

    def nodes(self, brightness: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each pixel's lower node index (N, H W) int64 and its weight on the upper one, from
        its `brightness` (N, 1, H, W) linear. A NaN brightness (an output a diverged model made
        NaN) reads node 0: cast to an integer it would index out of range."""
        u = torch.log1p(torch.clamp(brightness, min=0.0)).flatten(1)
        u = torch.where(torch.isnan(u), 0.0, u)
        p = torch.clamp(u * ((self.bins - 1) / self.range), 0.0, self.bins - 1.0)
        lower = torch.clamp(torch.floor(p), max=self.bins - 2.0)
        return lower.to(torch.int64), p - lower

    def statistics(self, out: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
        """This frame's (N, 2 K) sums [sum w out label, sum w out^2] per node, each pixel at the
        node of its `guide` brightness; `out`, `label` (N, 3, H, W) linear radiance."""
        w = 1.0 / (out * out + self.eps)
        per_pixel = torch.stack(((w * out * label).sum(1), (w * out * out).sum(1)), 1).flatten(2)
        lower, f = self.nodes(self.guide(out))
        k = self.bins
        split = torch.cat((per_pixel * (1.0 - f).unsqueeze(1), per_pixel * f.unsqueeze(1)), 2)
        index = torch.cat((lower, lower + 1), 1).unsqueeze(1).expand(-1, 2, -1)
        sums = torch.zeros(out.shape[0], 2, k, dtype=out.dtype, device=out.device)
        return sums.scatter_add(2, index, split).flatten(1)

    def guide(self, out: torch.Tensor) -> torch.Tensor:
        """The brightness a pixel's statistics are binned by: the mean of `out` over channels
        and the (2 blur + 1)^2 pixels around it (N, 1, H, W). A pixel's own samples are in its
        output, and binned by that alone it lands in a dark node partly because its samples
        were dark, where the label is dark too: the dark nodes' gain then falls below 1 where
        the truth is above (committed seq_002: label / output 0.82 in the darkest node,
        reference / output 1.12). Its neighbours dilute that."""
        lum = out.mean(dim=1, keepdim=True)
        if not self.blur:
            return lum
        side = 2 * self.blur + 1
        return F.avg_pool2d(lum, side, 1, self.blur, count_include_pad=False)

    def gains(self, stats: torch.Tensor) -> torch.Tensor:
        """(N, K) gains of the (N, 2 K) statistics."""
        num, den = stats[:, : self.bins], stats[:, self.bins :]
        return torch.clamp((num + self.prior) / (den + self.prior), 1.0 / self.limit, self.limit)

    def apply(self, out: torch.Tensor, stats: torch.Tensor) -> torch.Tensor:
        """`out` (N, 3, H, W) times the curve's gain at each pixel's brightness."""
        lower, f = self.nodes(out.mean(dim=1, keepdim=True))
        g = self.gains(stats)
        gain = torch.gather(g, 1, lower) * (1.0 - f) + torch.gather(g, 1, lower + 1) * f
        return out * gain.reshape(out.shape[0], 1, *out.shape[2:])


__all__ = ["GainCurve"]
