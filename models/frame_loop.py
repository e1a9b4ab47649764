"""`FrameLoop`: run a model frame after frame the way the runtime executor runs its export.

Per frame: replicate-pad H and W by the model's `edge_margin` on every side, then (bottom, right)
to its `pad_multiple`, run with the
state carried from the previous frame (zero state and reset = 1 on the first frame, after
`reset()` and when the frame size changes), crop the output back. Training (clips, with
gradients), validation, the export check and the benchmarks all use this one loop (after
Open Image Denoise's `training/infer.py` `Infer.__call__`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

import numpy as np
import torch
import torch.nn.functional as F

from rtdenoise.runtime.arrays import padded_size
from rtdenoise.runtime.contract import BUFFER_RANK

from .base import DenoiserModel
from .device import model_device

Frame = Mapping[str, "torch.Tensor | np.ndarray"]


def pad_to_multiple(x: torch.Tensor, multiple: int, margin: int = 0) -> torch.Tensor:
    """Replicate-pad the last two axes of (N, C, H, W) `x` (or (N, S, C, H, W)): `margin`
    pixels on every side, then up to multiples of `multiple` (bottom, right)."""
    h, w = x.shape[-2:]
    hp, wp = padded_size((h, w), multiple, margin)
    if (hp, wp) == (h, w):
        return x
    flat = x.reshape(-1, *x.shape[-3:])  # replicate padding takes 4-D tensors
    pads = (margin, wp - w - margin, margin, hp - h - margin)
    return F.pad(flat, pads, mode="replicate").reshape(*x.shape[:-2], hp, wp)


class FrameLoop:
    """Stateful frame-by-frame driver of a `DenoiserModel` (see the module docstring).

    Frames are dicts name -> (N, C, H, W) tensors, or (C, H, W) tensors / numpy arrays for
    N = 1 (the rank-5 `samples`: (N, S, C, H, W) or (S, C, H, W)); only the model's `inputs`
    are read, and moved to the model's device. Gradients flow unless the caller disables them.
    """

    def __init__(self, model: DenoiserModel, outer: bool = False) -> None:
        self.model = model
        self.outer = outer  # the outer training's unroll: zero states via `training_state`
        self.device = model_device(model)
        self.state: dict[str, torch.Tensor] | None = None
        self._key: tuple | None = None

    def reset(self) -> None:
        """Forget the history: the next frame starts from zero state with reset = 1."""
        self.state = None

    def _tensors(self, frame: Frame) -> dict[str, torch.Tensor]:
        out = {}
        for name in self.model.inputs:
            x = frame[name]
            x = torch.from_numpy(np.ascontiguousarray(x)) if isinstance(x, np.ndarray) else x
            x = x.to(self.device, non_blocking=True)
            out[name] = x if x.dim() == BUFFER_RANK.get(name, 4) else x.unsqueeze(0)
        return out

    def __call__(self, frame: Frame, reset: bool = False) -> torch.Tensor:
        """Denoise one frame; returns (N, 3, H, W) at the frame's own size."""
        buffers = self._tensors(frame)
        first = buffers[self.model.inputs[0]]
        (n, (h, w)), device = (first.shape[0], first.shape[-2:]), first.device
        m, margin = self.model.pad_multiple, self.model.edge_margin
        key = (n, h, w, device)
        if reset or self.state is None or key != self._key:
            hp, wp = padded_size((h, w), m, margin)
            self.state = self.model.initial_state(n, hp, wp, device=device)
            if self.outer:
                self.state = self.model.training_state(self.state)
            self._key, reset = key, True
        padded = {k: pad_to_multiple(v, m, margin) for k, v in buffers.items()}
        flag = torch.tensor(1.0 if reset else 0.0, device=device)
        output, self.state = self.model(padded, self.state, flag)
        return output[..., margin : margin + h, margin : margin + w]

    def run(self, frames: Iterable[Frame]) -> Iterator[torch.Tensor]:
        """Outputs of consecutive frames of one sequence (starts a new history)."""
        self.reset()
        for frame in frames:
            yield self(frame)


def unroll(model: DenoiserModel, clips: Mapping[str, torch.Tensor]) -> torch.Tensor:
    """Run `model` over clips (B, T, C, H, W) from a fresh history; returns (B, T, 3, H, W).
    The training unroll: each clip starts from `model.training_state` of the zero state."""
    t = next(iter(clips.values())).shape[1]
    loop = FrameLoop(model, outer=True)
    return torch.stack(
        list(loop.run({name: clip[:, i] for name, clip in clips.items()} for i in range(t))),
        dim=1,
    )
