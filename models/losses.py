"""Training losses: SMAPE (Lee24 eq. (5)), temporal SMAPE (Isik21 eq. (12)) and Open Image
Denoise's L1 + MS-SSIM on a perceptual transfer curve; `LOSSES` names the choices of
`denoise-train --loss`, and relMSE (`--relmse-weight`), relative L1 (`--rel-l1-weight`) or the
relative L1 of the dark pixels beside bright ones (`--dark-edge-weight`) may be added to any of
them.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

# relMSE with the epsilon of the metric the benchmarks report: unbounded where SMAPE saturates
# at 1, so a small bright light smeared into its dark neighbours costs in training what it costs
# in the metric.
from rtdenoise.runtime.sequences.metrics import RELMSE_EPS

from .msssim import ms_ssim
from .transfer import exposed_transfer, luminance

SMAPE_EPS = 1e-3  # Lee24 eq. (5): epsilon = 0.001
# relative L1's floor: sqrt(RELMSE_EPS), so that both relative terms call the same pixels dark
REL_L1_EPS = RELMSE_EPS**0.5
# Zhao et al. 2017 ("Loss functions for image restoration with neural networks", eq. (4)):
# alpha = 0.84 on MS-SSIM, 1 - alpha on L1; the mix Open Image Denoise trains with.
MS_SSIM_WEIGHT = 0.84
L1_WEIGHT = 1.0 - MS_SSIM_WEIGHT

LossFn = Callable[[torch.Tensor, torch.Tensor, float], torch.Tensor]


def smape(output: torch.Tensor, target: torch.Tensor, eps: float = SMAPE_EPS) -> torch.Tensor:
    """Mean over pixels and colour channels of |o - t| / (|o| + |t| + eps).

    Lee24 eq. (5), per colour channel (Isik21 eq. (11) sums the channel vector's L1 norms
    first; the per-channel form is Lee24's and the one runtime/metrics reports).
    """
    return ((output - target).abs() / (output.abs() + target.abs() + eps)).mean()


def relmse(output: torch.Tensor, target: torch.Tensor, eps: float = RELMSE_EPS) -> torch.Tensor:
    """Mean over pixels and colour channels of (o - t)^2 / (t^2 + eps), on raw radiance."""
    return ((output - target) ** 2 / (target**2 + eps)).mean()


def relative_l1(
    output: torch.Tensor, target: torch.Tensor, eps: float = REL_L1_EPS
) -> torch.Tensor:
    """Mean over pixels and colour channels of |o - t| / (|t| + eps), on raw radiance.

    Like relMSE it does not saturate (SMAPE's gradient falls as 1 / o^2 once o >> t, so a light
    smeared onto a dark wall is almost free), but its gradient is bounded by 1 / eps whatever
    the error: a few smeared pixels cannot swamp the rest of the batch, as relMSE's squares do.
    """
    return relative_error(output, target, eps).mean()


def relative_error(
    output: torch.Tensor, target: torch.Tensor, eps: float = REL_L1_EPS
) -> torch.Tensor:
    """Per pixel and channel |o - t| / (|t| + eps): what `relative_l1` averages."""
    return (output - target).abs() / (target.abs() + eps)


# A pixel is "dark beside a bright one" when the brightest reference pixel within
# DARK_EDGE_RADIUS of it is at least DARK_EDGE_BRIGHT and DARK_EDGE_CONTRAST times its own
# luminance: the pixels a kernel smears a small light into (0.65 % of the training clips').
DARK_EDGE_RADIUS = 2
DARK_EDGE_BRIGHT = 0.5
DARK_EDGE_CONTRAST = 20.0


def dark_edge_mask(target: torch.Tensor) -> torch.Tensor:
    """(..., 3, H, W) reference -> (..., 1, H, W) float mask of its dark pixels beside bright ones
    (DARK_EDGE_RADIUS, DARK_EDGE_BRIGHT, DARK_EDGE_CONTRAST)."""
    lum = luminance(target)
    flat = lum.reshape(-1, 1, *lum.shape[-2:])
    size = 2 * DARK_EDGE_RADIUS + 1
    brightest = torch.nn.functional.max_pool2d(flat, size, stride=1, padding=DARK_EDGE_RADIUS)
    mask = (brightest >= DARK_EDGE_BRIGHT) & (flat * DARK_EDGE_CONTRAST <= brightest)
    return mask.to(target.dtype).reshape(*lum.shape[:-2], 1, *lum.shape[-2:])


def dark_edge_l1(
    output: torch.Tensor, target: torch.Tensor, eps: float = REL_L1_EPS
) -> torch.Tensor:
    """Relative L1 (`relative_l1`) on the dark pixels beside bright ones (`dark_edge_mask`),
    zero elsewhere, averaged over every pixel: a weight on exactly the pixels where a kernel
    smears a small light into its dark neighbours, which the plain relative L1 weighs like any
    other (they are under 1 % of a clip)."""
    return (relative_error(output, target, eps) * dark_edge_mask(target)).mean()


def temporal_smape(
    outputs: torch.Tensor, targets: torch.Tensor, eps: float = SMAPE_EPS
) -> torch.Tensor:
    """SMAPE of the frame differences (Isik21 eq. (12)); time is dim 1 of (N, T, C, H, W).

    Zero when T < 2 (there is no difference to compare).
    """
    if outputs.shape[1] < 2:
        return outputs.new_zeros(())
    d_out = outputs[:, 1:] - outputs[:, :-1]
    d_ref = targets[:, 1:] - targets[:, :-1]
    return smape(d_out, d_ref, eps)


def sequence_loss(
    outputs: torch.Tensor,
    targets: torch.Tensor,
    temporal_weight: float = 0.25,
    eps: float = SMAPE_EPS,
) -> torch.Tensor:
    """Isik21 eq. (9) without the regulariser: SMAPE + w * temporal SMAPE over (N, T, C, H, W)."""
    loss = smape(outputs, targets, eps)
    if temporal_weight:
        loss = loss + temporal_weight * temporal_smape(outputs, targets, eps)
    return loss


def l1_ms_ssim_loss(
    outputs: torch.Tensor, targets: torch.Tensor, temporal_weight: float = 0.0
) -> torch.Tensor:
    """Open Image Denoise's loss on clips (N, T, 3, H, W): 0.16 L1 + 0.84 (1 - MS-SSIM), both
    on T(e x) (models/transfer.py: e = the auto-exposure of each clip's reference, T the
    PU-like curve), MS-SSIM per frame with range 1 (models/msssim.py: fewer scales on small
    crops). Plus temporal_weight x the L1 of the frame differences in the same domain (OIDN
    has no temporal term; 0 gives its loss exactly).
    """
    if outputs.dim() == 4:  # single frames (N, 3, H, W)
        outputs, targets = outputs[:, None], targets[:, None]
    out, ref = exposed_transfer(outputs, targets)
    frames_out = out.reshape(-1, *out.shape[-3:])
    frames_ref = ref.reshape(-1, *ref.shape[-3:])
    l1 = (out - ref).abs().mean()
    loss = L1_WEIGHT * l1 + MS_SSIM_WEIGHT * (1.0 - ms_ssim(frames_out, frames_ref).mean())
    if temporal_weight and out.shape[1] > 1:
        d_out = out[:, 1:] - out[:, :-1]
        d_ref = ref[:, 1:] - ref[:, :-1]
        loss = loss + temporal_weight * (d_out - d_ref).abs().mean()
    return loss


# `paper`: the family's own `loss` (each paper's: SMAPE + temporal SMAPE for afn and wskp,
# Isik21 eq. (9) with its regulariser for affinity, Meng20's gamma L1 for nbg).
LOSSES: dict[str, LossFn | None] = {
    "paper": None,
    "smape": sequence_loss,
    "l1-ms-ssim": l1_ms_ssim_loss,
}


def training_loss(
    name: str,
    model: torch.nn.Module,
    relmse_weight: float = 0.0,
    rel_l1_weight: float = 0.0,
    dark_edge_weight: float = 0.0,
    first_frame_weight: float = 0.0,
) -> LossFn:
    """The loss `denoise-train --loss name` minimises for `model`: (outputs, reference,
    temporal_weight) -> scalar. A replacement of the paper's loss keeps a family's
    regulariser where the family exposes one as `model.regulariser()` (a scalar, or None).
    `relmse_weight` / `rel_l1_weight` / `dark_edge_weight` > 0 add that multiple of relMSE
    (`relmse`) / relative L1 (`relative_l1`) / relative L1 of the dark pixels beside bright ones
    (`dark_edge_l1`) of the outputs to the loss. `first_frame_weight` > 0 adds that multiple of
    the same loss (temporal term off) on each clip's first frame, the one that starts without
    history (clips never cross a cut): what a shot's first frame costs where a model leans on
    its history (a family's regulariser still counts once: `regulariser()` empties on read)."""
    if name not in LOSSES:
        raise ValueError(f"unknown loss {name!r}; choose one of {', '.join(LOSSES)}")
    extra = {
        "relmse_weight": (relmse_weight, relmse),
        "rel_l1_weight": (rel_l1_weight, relative_l1),
        "dark_edge_weight": (dark_edge_weight, dark_edge_l1),
    }
    weights = {label: weight for label, (weight, _) in extra.items()}
    for label, weight in {**weights, "first_frame_weight": first_frame_weight}.items():
        if weight < 0:
            raise ValueError(f"{label} must be >= 0, got {weight}")
    fn = LOSSES[name]
    hook = getattr(model, "regulariser", None)
    if fn is None:
        base = model.loss
    elif not callable(hook):
        base = fn
    else:

        def base(outputs, reference, temporal_weight):
            loss = fn(outputs, reference, temporal_weight)
            reg = hook()
            return loss if reg is None else loss + reg

    terms = [(weight, term) for weight, term in extra.values() if weight]

    def with_terms(outputs, reference, temporal_weight):
        loss = base(outputs, reference, temporal_weight)
        for weight, term in terms:
            loss = loss + weight * term(outputs, reference)
        return loss

    whole = with_terms if terms else base
    if not first_frame_weight:
        return whole

    def with_first_frames(outputs, reference, temporal_weight):
        loss = whole(outputs, reference, temporal_weight)  # first: it takes the regulariser
        return loss + first_frame_weight * whole(outputs[:, :1], reference[:, :1], 0.0)

    return with_first_frames
