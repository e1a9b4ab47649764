"""ConvWeightGrad: the weight gradient of a stride-1 K x K convolution (an online model's
backward pass, crossreg's U-Net).

    grad_weight[o, i, ky, kx] = sum_{n, y, x} grad_output[n, o, y, x]
                                              * input[n, i, y + ky - p, x + kx - p]

(input 0 outside the image; grad_output (N, C_out, H + 2p - K + 1, W + 2p - K + 1)). This is
what aten's `convolution_backward` gives for the weight of `conv2d(input, weight, padding=p)`
(no dilation, one group). The traced backward spelled it as one MatMul per kernel tap over a
shifted copy of the input (Pad, Slice, Reshape, Transpose: models/online.py), 9 x 4 nodes and
copies of every input per 3 x 3 convolution; one op reads each tensor in place.
"""

from __future__ import annotations

import numpy as np

from .spec import Arg, OpSpec


def _check(shapes, attrs) -> None:
    k, p = attrs["kernel_size"], attrs["padding"]
    if k < 1 or not 0 <= p < k:
        raise ValueError(f"ConvWeightGrad: kernel_size {k}, padding {p}; need 0 <= padding < K")
    (n, _, h, w), (ng, _, hg, wg) = shapes
    if ng != n or (hg, wg) != (h + 2 * p - k + 1, w + 2 * p - k + 1):
        raise ValueError(
            f"ConvWeightGrad: grad_output has shape {tuple(shapes[1])}; expected N = {n} and "
            f"H, W = {h + 2 * p - k + 1}, {w + 2 * p - k + 1} (input {tuple(shapes[0])}, "
            f"kernel {k}, padding {p})"
        )


def _output_shapes(shapes, attrs) -> list:
    k = attrs["kernel_size"]
    return [(shapes[1][1], shapes[0][1], k, k)]


def _example_inputs(shape, attrs, rng: np.random.Generator) -> list[np.ndarray]:
    """An activation-like input (ReLU'd, a third zeros) with C channels and a gradient of
    2 C + 1 channels (more outputs than inputs and odd counts: every blocking's remainder)."""
    n, c, h, w = shape
    k, p = attrs["kernel_size"], attrs["padding"]
    x = np.maximum(rng.standard_normal((n, c, h, w)), -0.3).astype(np.float32)
    g = rng.standard_normal((n, 2 * c + 1, h + 2 * p - k + 1, w + 2 * p - k + 1))
    return [x, (1e-3 * g).astype(np.float32)]


SPEC = OpSpec(
    name="ConvWeightGrad",
    doc="grad_weight[o,i,ky,kx] = sum_{n,y,x} grad_output[n,o,y,x] input[n,i,y+ky-p,x+kx-p] "
    "(0 outside): the weight gradient of a stride-1 K x K convolution with padding p",
    inputs=(Arg("input"), Arg("grad_output")),
    outputs=(Arg("grad_weight"),),
    attrs=("kernel_size", "padding"),
    default_attrs={"kernel_size": 3, "padding": 1},
    example_attrs=(
        {"kernel_size": 3, "padding": 1},
        {"kernel_size": 3, "padding": 0},
        {"kernel_size": 5, "padding": 2},
        {"kernel_size": 1, "padding": 0},
    ),
    output_shapes=_output_shapes,
    check=_check,
    example_inputs=_example_inputs,
    example_shapes=((1, 3, 13, 17), (2, 4, 8, 6), (1, 1, 5, 5), (1, 8, 24, 40)),
)
