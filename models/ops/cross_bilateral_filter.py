"""CrossBilateralFilter in torch form (Choi24 eqs. (8)-(9)); the op is defined in
rtdenoise.ops.cross_bilateral_filter.

Two differentiable routes to the bandwidth gradient, equal by construction (tested):
- autograd through `cross_bilateral_filter_reference` (the numeric reference);
- the custom op's registered backward, which needs only standard ops on the op's own extra
  outputs: d L / d band_k = -sum(g_sum * dsum[k]) per buffer (band_rho, band_n and band_p are
  shared by both buffers: their gradients add). This is the backward the online-learning
  ONNX graph carries, and the one `cross_bilateral_filter` uses in PyTorch too, so that PyTorch
  and ONNX Runtime learn through the same formula (and PyTorch keeps no 121-tap autograd graph).
"""

from __future__ import annotations

import torch

from ._mirror import mirror_pad
from .export_mode import exporting
from .torch_op import torch_op


@torch_op("CrossBilateralFilter")
def cross_bilateral_filter_reference(
    pilot_a: torch.Tensor,
    pilot_b: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    band: torch.Tensor,
    window: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(sum_a, sum_b, dsum_a, dsum_b), Choi24 eq. (9); see rtdenoise.ops.cross_bilateral_filter."""
    h, w = pilot_a.shape[-2:]
    r = window // 2
    centre = torch.cat((pilot_a, pilot_b, albedo, normal), dim=1)
    padded = mirror_pad(centre, r)
    band_a, band_b, band_rho, band_n, band_p = band.split(1, dim=1)
    sums: dict[str, list[torch.Tensor]] = {"a": [], "b": []}
    dsums: dict[str, list[torch.Tensor]] = {"a": [], "b": []}
    for dy in range(window):
        for dx in range(window):
            tap = padded[..., dy : dy + h, dx : dx + w]
            d2 = (tap - centre) ** 2
            dist_rho = d2[:, 6:9].sum(dim=1, keepdim=True)
            dist_n = d2[:, 9:12].sum(dim=1, keepdim=True)
            dist_p = float((dy - r) ** 2 + (dx - r) ** 2) / float(r * r)
            shared = band_rho * dist_rho + band_n * dist_n + band_p * dist_p
            for key, sl, band_f in (("a", slice(0, 3), band_a), ("b", slice(3, 6), band_b)):
                f = tap[:, sl]
                dist_f = d2[:, sl].sum(dim=1, keepdim=True)
                m = torch.exp(-band_f * dist_f - shared)
                terms = [m * f, m]
                for dist in (dist_f, dist_rho, dist_n, dist_p):
                    md = m * dist
                    terms += [md * f, md]
                sums[key] = _add(sums[key], terms[:2])
                dsums[key] = _add(dsums[key], terms[2:])
    return (
        torch.cat(sums["a"], dim=1),
        torch.cat(sums["b"], dim=1),
        torch.cat(dsums["a"], dim=1),
        torch.cat(dsums["b"], dim=1),
    )


def _add(acc: list[torch.Tensor], terms: list[torch.Tensor]) -> list[torch.Tensor]:
    return terms if not acc else [a + t for a, t in zip(acc, terms, strict=True)]


def band_gradient(
    grad_sum_a: torch.Tensor | None,
    grad_sum_b: torch.Tensor | None,
    dsum_a: torch.Tensor,
    dsum_b: torch.Tensor,
) -> torch.Tensor:
    """d L / d band (N, 5, H, W) from d L / d sum_a, d L / d sum_b (N, 4, H, W) and the op's
    dsum outputs: d sum / d band_k = -dsum[k] (standard ops only)."""
    n, _, h, w = dsum_a.shape

    def per_distance(grad: torch.Tensor | None, dsum: torch.Tensor) -> torch.Tensor:
        if grad is None:
            return dsum.new_zeros(n, 4, h, w)
        return -(dsum.reshape(n, 4, 4, h, w) * grad.unsqueeze(1)).sum(dim=2)

    ga, gb = per_distance(grad_sum_a, dsum_a), per_distance(grad_sum_b, dsum_b)
    return torch.cat((ga[:, :1], gb[:, :1], ga[:, 1:] + gb[:, 1:]), dim=1)


def _setup_context(ctx, inputs, output) -> None:
    ctx.save_for_backward(output[2], output[3])


def _backward(ctx, grad_sum_a, grad_sum_b, _grad_dsum_a, _grad_dsum_b):
    dsum_a, dsum_b = ctx.saved_tensors
    return None, None, None, None, band_gradient(grad_sum_a, grad_sum_b, dsum_a, dsum_b), None


cross_bilateral_filter_reference.custom.register_autograd(_backward, setup_context=_setup_context)


def cross_bilateral_filter(
    pilot_a: torch.Tensor,
    pilot_b: torch.Tensor,
    albedo: torch.Tensor,
    normal: torch.Tensor,
    band: torch.Tensor,
    window: int = 11,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Choi24 eq. (9) over a `window`^2 window: (sum_a, sum_b, dsum_a, dsum_b) (see the op).

    Differentiable w.r.t. `band` through the op's registered backward (module docstring);
    the custom op is used in eager mode too, so PyTorch and the exported graph share it.
    """
    with exporting():
        return cross_bilateral_filter_reference(
            pilot_a, pilot_b, albedo, normal, band, window=window
        )
