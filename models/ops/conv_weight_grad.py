"""ConvWeightGrad in torch form; the op is defined in rtdenoise.ops.conv_weight_grad.

The reference is the convolution of the batch-transposed tensors (the input's channels as a
batch, the gradient's as the filters, the batch as the summed axis): aten's own identity for
the weight gradient of a stride-1 convolution.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .torch_op import torch_op


@torch_op("ConvWeightGrad")
def conv_weight_grad(
    input: torch.Tensor, grad_output: torch.Tensor, kernel_size: int, padding: int
) -> torch.Tensor:
    """d L / d weight (C_out, C_in, K, K) of `conv2d(input, weight, padding=padding)` given
    d L / d output; see rtdenoise.ops.conv_weight_grad."""
    del kernel_size  # the output's size follows from the shapes
    per_input = F.conv2d(input.transpose(0, 1), grad_output.transpose(0, 1), padding=padding)
    return per_input.transpose(0, 1).contiguous()
