"""Contenders of `denoise-bench compare` that need torch (runtime.compare is torch-free).

- `eager_contender`: a checkpoint's model in PyTorch eager, in its deployed form (RepVGG
  branches folded, eval mode: the network the ONNX file holds), on any torch device, driven by
  the one frame loop (models.frame_loop: padded, state carried, cropped).
- `oidn_torch_contender`: Open Image Denoise on a torch device (pyoidn takes CUDA tensors).

Inputs are moved to the device before the clock starts (`prepare`); the time includes the
copy of the output back to a numpy array, as a host that reads the result pays it.
"""

from __future__ import annotations

import os

import numpy as np
import torch

from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.models.device import torch_device
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.runtime.sequences.compare import OIDN_BUFFERS, Contender, Frame, oidn_contender

from .deploy import to_deploy


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def eager_contender(name: str, checkpoint: str | os.PathLike, device: str = "cpu") -> Contender:
    """The checkpoint's deployed model in PyTorch eager on `device`."""
    dev = torch_device(device)
    model, _ = load_checkpoint(checkpoint)
    model = to_deploy(model, inplace=True).to(dev).requires_grad_(False)
    loop = FrameLoop(model)

    def prepare(frame: Frame) -> dict[str, torch.Tensor]:
        return {k: torch.from_numpy(np.ascontiguousarray(frame[k])).to(dev) for k in model.inputs}

    @torch.no_grad()  # not inference_mode: an online model (crossreg) takes gradients inside
    def denoise(tensors: dict[str, torch.Tensor]) -> np.ndarray:
        out = loop(tensors)[0].cpu().numpy()
        _sync(dev)
        return out

    def fresh() -> Contender:  # the same checkpoint again, with a state of its own
        return eager_contender(name, checkpoint, device)

    return Contender(name, denoise, loop.reset, tuple(model.inputs), prepare, fresh)


def oidn_torch_contender(quality: str = "high", device: str = "cuda") -> Contender:
    """OIDN (RT filter, HDR, albedo + normal) on torch tensors of `device` (CUDA: OIDN's GPU
    device, as a PyTorch renderer would call it)."""
    dev = torch_device(device)
    host = oidn_contender(quality)  # checks the quality and pyoidn; its clamps and HWC layout
    import pyoidn

    def prepare(frame: Frame) -> tuple[torch.Tensor, ...]:
        return tuple(torch.from_numpy(a).to(dev) for a in host.prepare(frame))

    def denoise(prepared: tuple[torch.Tensor, ...]) -> np.ndarray:
        color, albedo, normal = prepared
        out = pyoidn.denoise(color, albedo, normal, hdr=True, quality=quality)
        return np.moveaxis(out.cpu().numpy(), -1, 0)

    return Contender(f"OIDN {quality} ({dev.type})", denoise, lambda: None, OIDN_BUFFERS, prepare)
