"""Online learning inside the model's own step: what a family that learns while it runs shares.

A model that learns online (Choi24) keeps its network weights theta, the optimiser moments and
the step count as contract state, and its `forward` does the whole frame: the forward pass
(displayed: it uses theta_{t-1}), the self-supervised loss, `torch.autograd.grad` and one
optimiser step, returning theta_t as next state. Nothing flows between frames but the state.

- `ParameterLayout`: a module's parameters <-> one flat vector (the `theta` state);
- `adam_step`: Adam (Kingma & Ba 2015, Algorithm 1, the form of torch.optim.Adam) as elementwise
  ops, gated by a 0/1 `learn` value (the host's freeze switch);
- `traced_step`: the step traced by `make_fx` into aten ops (autograd's backward included),
  which `torch.onnx.export` then converts: `torch.export` cannot trace `autograd.grad` itself
  (research-notes, "Training inside ONNX Runtime"). Two backward ops have no ONNX translation
  and are decomposed here: `convolution_backward` (input gradient by a convolution with the
  flipped, transposed weights; the weight gradient of a square K x K kernel (K > 1) by the
  custom op ConvWeightGrad, of a 1x1 one by a matrix product; the 1x1 stride-2 transposed
  convolution by a strided slice, a 1x1 convolution and a matrix product) and
  `max_pool2d_with_indices_backward` (ScatterElements-add of the gradient at the indices).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from .ops.conv_weight_grad import conv_weight_grad
from .ops.export_mode import exporting

aten = torch.ops.aten


@dataclass(frozen=True)
class ParameterLayout:
    """The order and shapes of a module's parameters inside the flat vector theta."""

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]

    @classmethod
    def of(cls, module: nn.Module) -> ParameterLayout:
        named = list(module.named_parameters())
        return cls(tuple(n for n, _ in named), tuple(tuple(p.shape) for _, p in named))

    @property
    def sizes(self) -> list[int]:
        out = []
        for shape in self.shapes:
            size = 1
            for d in shape:
                size *= d
            out.append(size)
        return out

    @property
    def size(self) -> int:
        return sum(self.sizes)

    def flatten(self, module: nn.Module) -> torch.Tensor:
        """theta (P,) from the module's parameters, in layout order (differentiable)."""
        params = dict(module.named_parameters())
        return torch.cat([params[n].reshape(-1) for n in self.names])

    def unflatten(self, theta: torch.Tensor) -> dict[str, torch.Tensor]:
        """{name: view of theta} for torch.func.functional_call."""
        parts = torch.split(theta, self.sizes)
        return {n: p.view(s) for n, p, s in zip(self.names, parts, self.shapes, strict=True)}

    def to_json(self) -> list[dict]:
        return [{"name": n, "shape": list(s)} for n, s in zip(self.names, self.shapes, strict=True)]


@dataclass(frozen=True)
class Adam:
    """Adam's constants (Kingma & Ba 2015)."""

    lr: float = 1e-3
    beta1: float = 0.9
    beta2: float = 0.999
    eps: float = 1e-7


def adam_step(
    theta: torch.Tensor,
    grad: torch.Tensor,
    m: torch.Tensor,
    v: torch.Tensor,
    t: torch.Tensor,
    learn: torch.Tensor,
    adam: Adam,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """(theta', m', v', t') after one Adam step (Kingma & Ba Alg. 1; t counts from 0), or the
    inputs unchanged where `learn` <= 0.5 (or is False: a boolean gate the caller shares with
    its other learned states). All elementwise: exports to standard ONNX ops."""
    t1 = t + 1.0
    m1 = adam.beta1 * m + (1.0 - adam.beta1) * grad
    v1 = adam.beta2 * v + (1.0 - adam.beta2) * grad * grad
    m_hat = m1 / (1.0 - torch.pow(adam.beta1, t1))
    v_hat = v1 / (1.0 - torch.pow(adam.beta2, t1))
    stepped = theta - adam.lr * m_hat / (torch.sqrt(v_hat) + adam.eps)
    gate = learn if learn.dtype == torch.bool else learn > 0.5
    return (
        torch.where(gate, stepped, theta),
        torch.where(gate, m1, m),
        torch.where(gate, v1, v),
        torch.where(gate, t1, t),
    )


# -- tracing the step ---------------------------------------------------------------------


def _convolution_backward(
    grad_out: torch.Tensor,
    inp: torch.Tensor,
    weight: torch.Tensor,
    bias_sizes: Sequence[int] | None,
    stride: Sequence[int],
    padding: Sequence[int],
    dilation: Sequence[int],
    transposed: bool,
    output_padding: Sequence[int],
    groups: int,
    output_mask: Sequence[bool],
) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]:
    """aten.convolution_backward in forward convolutions (2-D, groups 1, no dilation):
    stride-1 convolutions, and 1x1 transposed convolutions without padding (any stride)."""
    if groups != 1 or any(d != 1 for d in dilation) or inp.dim() != 4:
        raise NotImplementedError("online export: only 2-D, ungrouped, undilated convolutions")
    grad_in = grad_w = grad_b = None
    if not transposed:
        if any(s != 1 for s in stride):
            raise NotImplementedError("online export: strided convolutions are not supported")
        if output_mask[0]:  # conv_transpose2d(grad_out, weight) as a forward convolution:
            # ONNX Runtime's ConvTranspose (GEMM + col2im) took 2.5 s of a 720p frame's
            # backward per wide layer, its Conv with the flipped, transposed weights a third
            k = weight.shape[2:]
            if any(p > kk - 1 for p, kk in zip(padding, k, strict=True)):
                raise NotImplementedError("online export: padding wider than the kernel")
            flipped = weight.transpose(0, 1).flip((2, 3))
            pad = [k[0] - 1 - padding[0], k[1] - 1 - padding[1]]
            grad_in = F.conv2d(grad_out, flipped, padding=pad)
        if output_mask[1]:
            k, (ph, pw) = tuple(weight.shape[2:]), padding
            if k[0] == k[1] > 1 and ph == pw:  # one ConvWeightGrad node (the C++ kernel)
                grad_w = conv_weight_grad(inp, grad_out, kernel_size=k[0], padding=ph)
            else:
                grad_w = _weight_gradient(inp, grad_out, k, (ph, pw))
    else:
        if tuple(weight.shape[2:]) != (1, 1) or any(p != 0 for p in padding):
            raise NotImplementedError("online export: only 1x1 transposed convolutions")
        sy, sx = stride
        picked = grad_out[:, :, ::sy, ::sx]  # where the inputs landed
        if output_mask[0]:
            grad_in = F.conv2d(picked, weight)
        if output_mask[1]:
            grad_w = _weight_gradient(picked, inp, (1, 1), (0, 0))  # (C_in, C_out, 1, 1)
    if output_mask[2]:
        grad_b = grad_out.sum(dim=(0, 2, 3))
    return grad_in, grad_w, grad_b


def _weight_gradient(
    inp: torch.Tensor, grad_out: torch.Tensor, kernel: tuple[int, int], padding: tuple[int, int]
) -> torch.Tensor:
    """d L / d weight (C_out, C_in, kh, kw) of a stride-1 convolution: per tap (ky, kx) one
    matrix product over the pixels, sum_p g[o, p] x_pad[i, p + k], of the tensor with more
    channels as it is and the one with fewer shifted (the copy). A batch of one frame; other
    batches take the convolution of the batch-transposed tensors. In ONNX Runtime at 720p these
    are 1.8x (8 x 24 channels) to 3.4x (16 x 48, half resolution) faster than that convolution
    (a K = H x W kernel)."""
    n, c_in = inp.shape[:2]
    c_out = grad_out.shape[1]
    (kh, kw), (ph, pw) = kernel, padding
    if n != 1:
        return F.conv2d(inp.transpose(0, 1), grad_out.transpose(0, 1), padding=[ph, pw]).transpose(
            0, 1
        )
    h, w = grad_out.shape[2:]
    x = F.pad(inp, (pw, pw, ph, ph)) if ph or pw else inp  # (1, C_in, h + kh - 1, w + kw - 1)
    taps = []
    if c_in <= c_out:  # shift x: g (C_out, hw) @ x_k^T (hw, C_in)
        g2 = grad_out.reshape(c_out, -1)
        for ky in range(kh):
            for kx in range(kw):
                x_k = x[0, :, ky : ky + h, kx : kx + w].reshape(c_in, -1)
                taps.append(torch.mm(g2, x_k.t()))
        return torch.stack(taps, dim=-1).reshape(c_out, c_in, kh, kw)
    x2 = x.reshape(c_in, -1)  # shift g by padding it onto x's grid: x (C_in, K) @ g_k^T
    for ky in range(kh):
        for kx in range(kw):
            g_k = F.pad(grad_out, (kx, kw - 1 - kx, ky, kh - 1 - ky)) if kh * kw > 1 else grad_out
            taps.append(torch.mm(x2, g_k.reshape(c_out, -1).t()))
    return torch.stack(taps, dim=-1).permute(1, 0, 2).reshape(c_out, c_in, kh, kw)


def _max_pool2d_backward(
    grad_out: torch.Tensor,
    inp: torch.Tensor,
    kernel_size,
    stride,
    padding,
    dilation,
    ceil_mode,
    indices: torch.Tensor,
) -> torch.Tensor:
    """aten.max_pool2d_with_indices_backward: add each gradient at its argmax (plane-flat index)."""
    n, c, h, w = inp.shape
    flat = grad_out.new_zeros(n, c, h * w)
    return flat.scatter_add(2, indices.flatten(2), grad_out.flatten(2)).view(n, c, h, w)


DECOMPOSITIONS = {
    aten.convolution_backward.default: _convolution_backward,
    aten.max_pool2d_with_indices_backward.default: _max_pool2d_backward,
}


class TracedStep(nn.Module):
    """A traced step behind the contract's `forward(*args)` signature."""

    def __init__(self, graph_module: nn.Module) -> None:
        super().__init__()
        self.graph_module = graph_module

    def forward(self, *args: torch.Tensor) -> tuple[torch.Tensor, ...]:
        return tuple(self.graph_module(*args))


def traced_step(module: nn.Module, example_args: tuple) -> TracedStep:
    """`module(*example_args)` traced into aten ops with symbolic shapes (autograd's backward
    and every custom op node included), for `torch.onnx.export`."""
    from torch.fx.experimental.proxy_tensor import make_fx

    with exporting():
        graph_module = make_fx(
            module,
            decomposition_table=DECOMPOSITIONS,
            tracing_mode="symbolic",
            _allow_non_fake_inputs=True,  # the module's weights: theta at initialisation
        )(*example_args)
    return TracedStep(graph_module)
