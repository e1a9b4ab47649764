"""Training losses: SMAPE (Lee24 eq. (5)) and temporal SMAPE (Isik21 eq. (12))."""

from __future__ import annotations

import torch

SMAPE_EPS = 1e-3  # Lee24 eq. (5): epsilon = 0.001


def smape(output: torch.Tensor, target: torch.Tensor, eps: float = SMAPE_EPS) -> torch.Tensor:
    """Mean over pixels and colour channels of |o - t| / (|o| + |t| + eps).

    Lee24 eq. (5), per colour channel (Isik21 eq. (11) sums the channel vector's L1 norms
    first; the per-channel form is Lee24's and the one runtime/metrics reports).
    """
    return ((output - target).abs() / (output.abs() + target.abs() + eps)).mean()


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
