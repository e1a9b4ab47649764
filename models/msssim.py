"""SSIM and multi-scale SSIM in torch, differentiable, for training losses.

SSIM (Wang et al. 2004, "Image quality assessment: from error visibility to structural
similarity"): an 11 x 11 Gaussian window (sigma 1.5) applied per channel without padding
('valid', so no border artefacts), C1 = (0.01 L)^2, C2 = (0.03 L)^2 with dynamic range L.

MS-SSIM (Wang, Simoncelli, Bovik 2003, "Multiscale structural similarity for image quality
assessment", eq. (7)): prod_{j<M} cs_j^beta_j * ssim_M^beta_M over M scales, each a 2 x 2
average-pooled copy of the previous, with the paper's exponents
beta = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333).

Small crops (stated choice): the paper's 5 scales need an image side of at least 11 x 2^4 =
176 px at the 'valid' window. `scales_for(side)` keeps the scales whose side is still >= the
window (256 px: 5, 128 px: 4, 64 px: 3, 32 px: 2, 16 px: 1) and uses the first M exponents
renormalised to sum 1; below 11 px the window shrinks to the largest odd size <= the side (at
least 3; smaller images are refused). cs and ssim are clamped to >= 1e-4 before the
fractional powers (a negative correlation would give NaN; pytorch-msssim uses a ReLU, whose
power has an infinite gradient at 0).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

WINDOW = 11
SIGMA = 1.5
K1, K2 = 0.01, 0.03
MS_SSIM_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)
_FLOOR = 1e-4


def window_for(side: int) -> int:
    """The Gaussian window used on an image whose smaller side is `side` (11, or smaller)."""
    if side < 3:
        raise ValueError(f"SSIM needs images of at least 3 x 3 pixels, got a side of {side}")
    return WINDOW if side >= WINDOW else side - (1 - side % 2)


def scales_for(side: int, window: int | None = None, most: int = len(MS_SSIM_WEIGHTS)) -> int:
    """How many MS-SSIM scales an image of smaller side `side` allows: each halves the side
    (floor), and the coarsest must still hold the window. At least 1."""
    window = window or window_for(side)
    m = 1
    while m < most and side // 2**m >= window:
        m += 1
    return m


def _gaussian(window: int, sigma: float, channels: int, like: torch.Tensor) -> torch.Tensor:
    r = torch.arange(window, dtype=like.dtype, device=like.device) - (window - 1) / 2
    g = torch.exp(-(r**2) / (2 * sigma**2))
    g = g / g.sum()
    return (g[:, None] * g[None, :]).expand(channels, 1, window, window).contiguous()


def _ssim_cs(
    x: torch.Tensor, y: torch.Tensor, kernel: torch.Tensor, data_range: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-image mean SSIM and contrast-structure term of (N, C, H, W) images."""
    c = x.shape[1]
    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, kernel, groups=c)

    mu_x, mu_y = blur(x), blur(y)
    var_x = blur(x * x) - mu_x**2
    var_y = blur(y * y) - mu_y**2
    cov = blur(x * y) - mu_x * mu_y
    cs = (2 * cov + c2) / (var_x + var_y + c2)
    luminance = (2 * mu_x * mu_y + c1) / (mu_x**2 + mu_y**2 + c1)
    return (luminance * cs).mean(dim=(1, 2, 3)), cs.mean(dim=(1, 2, 3))


def ssim(x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0) -> torch.Tensor:
    """Mean SSIM of (N, C, H, W) images (one value per image, shape (N,))."""
    window = window_for(min(x.shape[-2:]))
    return _ssim_cs(x, y, _gaussian(window, SIGMA, x.shape[1], x), data_range)[0]


def ms_ssim(
    x: torch.Tensor, y: torch.Tensor, data_range: float = 1.0, scales: int | None = None
) -> torch.Tensor:
    """MS-SSIM of (N, C, H, W) images, shape (N,); `scales` defaults to `scales_for` the
    smaller side (see the module docstring for small crops)."""
    if x.shape != y.shape or x.dim() != 4:
        raise ValueError(f"ms_ssim expects two (N, C, H, W) tensors, got {x.shape}, {y.shape}")
    side = min(x.shape[-2:])
    window = window_for(side)
    m = scales or scales_for(side, window)
    if side // 2 ** (m - 1) < window:
        raise ValueError(f"{m} MS-SSIM scales need a side of {window * 2 ** (m - 1)}, got {side}")
    weights = torch.tensor(MS_SSIM_WEIGHTS[:m], dtype=x.dtype, device=x.device)
    weights = weights / weights.sum()
    kernel = _gaussian(window, SIGMA, x.shape[1], x)
    terms = []
    for j in range(m):
        s, cs = _ssim_cs(x, y, kernel, data_range)
        terms.append((s if j == m - 1 else cs).clamp_min(_FLOOR))
        if j < m - 1:
            x, y = F.avg_pool2d(x, 2), F.avg_pool2d(y, 2)
    return torch.prod(torch.stack(terms, dim=-1) ** weights, dim=-1)


__all__ = ["MS_SSIM_WEIGHTS", "ms_ssim", "scales_for", "ssim", "window_for"]
