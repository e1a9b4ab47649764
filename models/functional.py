"""Small tensor functions the families share, written for what they export to."""

from __future__ import annotations

import torch


def channel_softmax(x: torch.Tensor) -> torch.Tensor:
    """Softmax over dim 1 of an NCHW tensor, spelled out (max, exp, sum, divide).

    Same values as torch.softmax(x, dim=1), but it exports to ReduceMax/Sub/Exp/ReduceSum/Div:
    ONNX Runtime's Softmax(axis=1) on NCHW is very slow on CPU (measured on AFN's 49-tap kernels at
    720p: 3.5 s per frame for the two Softmax nodes, the spelled-out form a few tens of ms).
    """
    e = torch.exp(x - x.amax(dim=1, keepdim=True))
    return e / e.sum(dim=1, keepdim=True)
