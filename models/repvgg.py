"""RepVGG blocks (Ding21, as used by Fan21 supplement s.1.1) and their structural
re-parameterisation into one convolution.

Training form: parallel k x k convolutions (Fan21: 5 x 5, 3 x 3, 1 x 1) plus an identity
branch where in == out channels, each optionally followed by BatchNorm2d, summed. The
activation is NOT part of the block: the model applies it after the sum (Fan21 Fig. 1 draws a
ReLU after the merged 5 x 5 conv, the official code and `models/families/wskp.py` use
LeakyReLU 0.1; the folded conv must equal the branch sum alone).

Deploy form (`RepVGGBlock.reparameterize`, called by `export.deploy.to_deploy`): one
K x K conv, K = the largest kernel size, weight = sum of the branches' kernels zero-padded
to K x K (centred), the identity as a centred delta, BN folded with its running statistics
(eval-mode semantics). Fan21 supplement s.1.1: "we construct a single 5 x 5 convolution
kernel with an element-wise addition to the trained and zero-padded parameters".
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn


def fold_bn(
    weight: torch.Tensor, bias: torch.Tensor | None, bn: nn.BatchNorm2d
) -> tuple[torch.Tensor, torch.Tensor]:
    """Fold an eval-mode BatchNorm2d into the conv (weight, bias) that precedes it.

    BN(conv(x)) = t * (W x + b - mean) + beta with t = gamma / sqrt(var + eps), so
    W' = W * t (per output channel) and b' = beta + (b - mean) * t (Ioffe15, Ding21 eq. 3).
    Works in the weight's dtype; pass float64 tensors for an exact fold.
    """
    if bn.running_mean is None or bn.running_var is None:
        raise ValueError("fold_bn needs a BatchNorm2d with running statistics")
    dtype = weight.dtype
    mean = bn.running_mean.to(dtype)
    std = torch.sqrt(bn.running_var.to(dtype) + bn.eps)
    gamma = bn.weight.to(dtype) if bn.weight is not None else torch.ones_like(mean)
    beta = bn.bias.to(dtype) if bn.bias is not None else torch.zeros_like(mean)
    if bias is None:
        bias = torch.zeros_like(mean)
    t = gamma / std
    return weight * t.view(-1, 1, 1, 1), beta + (bias.to(dtype) - mean) * t


def pad_kernel(weight: torch.Tensor, size: int) -> torch.Tensor:
    """Zero-pad an (O, I, k, k) kernel to (O, I, size, size), centred (k, size odd)."""
    k = weight.shape[-1]
    p = (size - k) // 2
    return F.pad(weight, (p, p, p, p))


def identity_kernel(
    channels: int, size: int, dtype: torch.dtype = torch.float32, device=None
) -> torch.Tensor:
    """(C, C, size, size) kernel of the identity map: a centred delta on the diagonal."""
    kernel = torch.zeros(channels, channels, size, size, dtype=dtype, device=device)
    c = size // 2
    kernel[torch.arange(channels), torch.arange(channels), c, c] = 1.0
    return kernel


class RepVGGBlock(nn.Module):
    """sum_k BN_k(conv_k(x)) [+ BN_id(x)]; no activation (see the module docstring).

    in_ch, out_ch: channels; kernel_sizes: odd sizes of the conv branches (Fan21: 5, 3, 1);
    identity: add the identity branch (None: where in_ch == out_ch, Fan21's rule);
    bn: BatchNorm2d after every branch (identity included, as in Ding21);
    bias: conv biases (redundant with bn but allowed).
    """

    def __init__(
        self,
        in_ch: int,
        out_ch: int,
        kernel_sizes: Sequence[int] = (5, 3, 1),
        identity: bool | None = None,
        bn: bool = False,
        bias: bool = False,
    ) -> None:
        super().__init__()
        kernel_sizes = tuple(int(k) for k in kernel_sizes)
        if not kernel_sizes or any(k < 1 or k % 2 == 0 for k in kernel_sizes):
            raise ValueError(f"RepVGGBlock kernel sizes must be odd and >= 1, got {kernel_sizes}")
        if identity is None:
            identity = in_ch == out_ch
        if identity and in_ch != out_ch:
            raise ValueError(f"identity branch needs in_ch == out_ch, got {in_ch} -> {out_ch}")
        self.in_ch, self.out_ch = in_ch, out_ch
        self.kernel_sizes = kernel_sizes
        self.size = max(kernel_sizes)
        self.branches = nn.ModuleList()
        for k in kernel_sizes:
            branch = nn.Sequential(nn.Conv2d(in_ch, out_ch, k, padding=k // 2, bias=bias))
            if bn:
                branch.append(nn.BatchNorm2d(out_ch))
            self.branches.append(branch)
        self.identity: nn.Module | None = None
        if identity:
            self.identity = nn.BatchNorm2d(out_ch) if bn else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = self.branches[0](x)
        for branch in self.branches[1:]:
            out = out + branch(x)
        if self.identity is not None:
            out = out + self.identity(x)
        return out

    @torch.no_grad()
    def folded_weights(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(weight (O, I, K, K), bias (O,) or None) of the equivalent single conv, in float64."""
        ref = self.branches[0][0].weight
        f64 = dict(dtype=torch.float64, device=ref.device)
        weight = torch.zeros(self.out_ch, self.in_ch, self.size, self.size, **f64)
        bias = torch.zeros(self.out_ch, **f64)
        has_bias = False
        for branch in self.branches:
            conv = branch[0]
            w = conv.weight.to(torch.float64)
            b = None if conv.bias is None else conv.bias.to(torch.float64)
            if len(branch) > 1:  # Conv -> BN
                w, b = fold_bn(w, b, branch[1])
            weight += pad_kernel(w, self.size)
            if b is not None:
                bias += b
                has_bias = True
        if self.identity is not None:
            w = identity_kernel(self.out_ch, self.size, **f64)
            if isinstance(self.identity, nn.BatchNorm2d):
                w, b = fold_bn(w, None, self.identity)
                bias += b
                has_bias = True
            weight += w
        return weight, (bias if has_bias else None)

    @torch.no_grad()
    def reparameterize(self) -> nn.Conv2d:
        """One K x K conv (padding K // 2) equal to the branch sum (BN in eval semantics)."""
        weight, bias = self.folded_weights()
        ref = self.branches[0][0].weight
        conv = nn.Conv2d(
            self.in_ch, self.out_ch, self.size, padding=self.size // 2, bias=bias is not None
        ).to(device=ref.device, dtype=ref.dtype)
        conv.weight.copy_(weight.to(ref.dtype))
        if bias is not None:
            conv.bias.copy_(bias.to(ref.dtype))
        return conv


__all__ = ["RepVGGBlock", "fold_bn", "identity_kernel", "pad_kernel"]
