"""The interface every denoiser family implements, mirroring the ONNX contract (design.md s.3).

A model maps one frame's canonical buffers plus its temporal state to the
denoised output and the next state. All temporal logic (reprojection,
accumulation, history rejection) lives inside `forward`, so that the exported
graph is self-contained and the executor only feeds state back.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from rtdenoise.runtime.buffers import BUFFER_CHANNELS  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class StateSpec:
    """One temporal tensor: `channels` x (H / scale) x (W / scale)."""

    name: str
    channels: int
    scale: int = 1


class DenoiserModel(nn.Module):
    """Base class of the denoiser families.

    Subclasses set `family`, `inputs` (canonical buffer names they read),
    `state_specs` and `pad_multiple`, and implement `forward`.
    """

    family: str = ""
    inputs: tuple[str, ...] = ()
    state_specs: tuple[StateSpec, ...] = ()
    pad_multiple: int = 1

    def forward(
        self,
        buffers: dict[str, torch.Tensor],
        state: dict[str, torch.Tensor],
        reset: torch.Tensor,
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """Denoise one frame.

        buffers: canonical name -> (N, C, H, W) float32, H and W multiples of `pad_multiple`.
        state: StateSpec.name -> (N, C, H/scale, W/scale); zeros on the first frame.
        reset: scalar float32 tensor, 1.0 to ignore the history (first frame, camera cut).
        Returns (output (N, 3, H, W) linear HDR, next state with the same keys and shapes).
        """
        raise NotImplementedError

    def initial_state(self, n: int, h: int, w: int) -> dict[str, torch.Tensor]:
        """Zero state for an N x H x W sequence (what the executor feeds on frame 0)."""
        return {
            s.name: torch.zeros(n, s.channels, h // s.scale, w // s.scale) for s in self.state_specs
        }

    def config(self) -> dict:
        """The JSON-able constructor arguments (stored in checkpoints and ONNX metadata).

        Families keep their config dataclass in `self.cfg` (with `to_dict()`)."""
        return self.cfg.to_dict()
