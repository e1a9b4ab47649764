"""What every denoiser family is: a `DenoiserModel` with a `FamilyConfig`, registered by name.

A model maps one frame's canonical buffers plus its temporal state to the denoised output
and the next state, mirroring the ONNX contract (docs/contract.md). All temporal logic
(reprojection, accumulation, history rejection) lives inside `forward`, so that the exported
graph is self-contained and the executor only feeds state back.

A family is one module of `rtdenoise.models.families` whose model class is decorated with
`@register_family`; its constructor takes a config dataclass derived from `FamilyConfig`
(one `from_dict` / `to_dict` / `validate` for all). See docs/architecture.md, "Adding a family".
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any, ClassVar

import torch
from torch import nn

from rtdenoise.runtime.contract import (
    BUFFER_CHANNELS,
    MAX_EDGE_MARGIN,
    Declaration,
    RuntimeOption,
    StateSpec,
)

from .losses import sequence_loss


def option_buffer(name: str) -> str:
    """The model buffer that holds run-time option `name` (`DenoiserModel.add_runtime_option`)."""
    return f"option_{name}"


__all__ = [
    "BUFFER_CHANNELS",
    "FAMILIES",
    "DenoiserModel",
    "FamilyConfig",
    "RuntimeOption",
    "StateSpec",
    "register_family",
]

PADDINGS = ("zeros", "replicate")  # the `padding` config key of afn, affinity and nbg


def check_padding(config: FamilyConfig) -> None:
    """`validate` helper: the config's `padding` is one of PADDINGS and its `edge_margin` an
    integer in 0..MAX_EDGE_MARGIN."""
    if config.padding not in PADDINGS:
        raise config.fail(f"padding must be one of {', '.join(PADDINGS)}, got {config.padding!r}")
    margin = config.edge_margin
    if isinstance(margin, bool) or not isinstance(margin, int):
        raise config.fail(f"edge_margin must be an integer, got {margin!r}")
    if not 0 <= margin <= MAX_EDGE_MARGIN:
        raise config.fail(f"edge_margin must be in 0..{MAX_EDGE_MARGIN}, got {margin}")


def pad_convs(module: nn.Module, mode: str) -> None:
    """Every k x k Conv2d of `module` sees past the frame's edge as `mode` says: "zeros" or
    "replicate" (the edge pixel repeated; exported as an ONNX Pad of mode edge)."""
    for conv in module.modules():
        if isinstance(conv, nn.Conv2d) and conv.padding != (0, 0):
            conv.padding_mode = mode


@dataclasses.dataclass(frozen=True)
class FamilyConfig:
    """Base of the family config dataclasses: JSON-able constructor arguments.

    Fields typed `tuple[...]` are read from JSON lists; `validate` (overridden by families,
    called by `from_dict`) raises ValueError naming the family, the key and the value.
    """

    family: ClassVar[str] = ""

    @classmethod
    def from_dict(cls, data: dict | None) -> FamilyConfig:
        """Defaults overridden by `data`; unknown keys or invalid values raise ValueError."""
        data = dict(data or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown {cls.family} config keys {unknown}; known: {sorted(names)}")
        hints = typing.get_type_hints(cls)
        for key, value in data.items():
            if typing.get_origin(hints[key]) is tuple and isinstance(value, (list, tuple)):
                data[key] = tuple(value)
        config = cls(**data)
        config.validate()
        return config

    @classmethod
    def of(cls, config: FamilyConfig | dict | None) -> FamilyConfig:
        """`config` as a validated instance of this class (a dict or None goes through
        `from_dict`); what a model's constructor calls."""
        if isinstance(config, cls):
            config.validate()
            return config
        if config is not None and not isinstance(config, dict):
            raise TypeError(f"{cls.family} config must be a {cls.__name__} or a dict")
        return cls.from_dict(config)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (tuples as lists) that `from_dict` turns back into this config."""
        return {
            k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()
        }

    def validate(self) -> None:
        """Raise ValueError for an invalid combination of values (families override)."""

    def fail(self, message: str) -> ValueError:
        """A ValueError prefixed with the family name, for `validate`."""
        return ValueError(f"{self.family} {message}")


class DenoiserModel(nn.Module):
    """Base class of the denoiser families.

    Subclasses set `family`, `config_class`, `example_config`, `inputs` (canonical buffer
    names they read), `state_specs`, `pad_multiple` and `input_note`, keep their config in
    `self.cfg`, and implement `forward` (and `loss` when the paper trains with another loss).
    """

    family: ClassVar[str] = ""
    config_class: ClassVar[type[FamilyConfig]] = FamilyConfig
    # A small configuration (dict for config_class.from_dict) that runs fast on a CPU: the
    # family-wide contract tests (tests/test_families.py) and smoke runs build it.
    example_config: ClassVar[dict[str, Any]] = {}
    inputs: tuple[str, ...] = ()
    state_specs: tuple[StateSpec, ...] = ()
    pad_multiple: int = 1
    input_note: str = ""
    # Scalars a runtime may change per session (e.g. a kernel size), each declared once with
    # `add_runtime_option`: the float32 buffer `option_<name>` of the model, exported as the
    # overridable initializer `option.<name>` (runtime.contract.RuntimeOption).
    runtime_options: tuple[RuntimeOption, ...] = ()
    cfg: FamilyConfig

    def add_runtime_option(self, option: RuntimeOption) -> torch.Tensor:
        """Declare a run-time option: listed in `runtime_options` and held as the buffer
        `option_<name>` (its default), which the forward passes to its ops unchanged."""
        self.runtime_options = (*self.runtime_options, option)
        name = option_buffer(option.name)
        self.register_buffer(name, torch.tensor(float(option.default)), persistent=False)
        return getattr(self, name)

    @property
    def edge_margin(self) -> int:
        """Pixels of the frame's edge repeated on every side before `forward` and cropped from
        its output (FrameLoop, the runtime; contract key `rtdenoise.edge_margin`), for weights
        that smear what lies at the frame's edge: the config's `edge_margin` (afn, affinity and
        nbg have the key, beside `padding`), 0 for a config without it."""
        return int(getattr(getattr(self, "cfg", None), "edge_margin", 0))

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

    def loss(
        self, outputs: torch.Tensor, reference: torch.Tensor, temporal_weight: float
    ) -> torch.Tensor:
        """Training loss of unrolled clips, outputs and reference (B, T, 3, H, W).

        Default: SMAPE (Lee24 eq. (5)) + temporal_weight * temporal SMAPE (Isik21 eq. (12)).
        """
        return sequence_loss(outputs, reference, temporal_weight)

    def initial_state(
        self, n: int, h: int, w: int, device: torch.device | str | None = None
    ) -> dict[str, torch.Tensor]:
        """Zero state for an N x H x W sequence (what the executor feeds on frame 0)."""
        return {
            s.name: torch.zeros(n, s.channels, *s.spatial(h, w), device=device)
            for s in self.state_specs
        }

    def training_state(self, state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The zero state `state` (from `initial_state`) as the outer, offline training unroll
        (`models.frame_loop.unroll`) starts a clip from. Default: unchanged. A family with host
        controls in its state sets them here (crossreg: `freeze` = 1, the online update off)."""
        return state

    def config(self) -> dict:
        """The JSON-able constructor arguments (stored in checkpoints and ONNX metadata)."""
        return self.cfg.to_dict()

    def export_module(self, contract_module: nn.Module, example_args: tuple) -> nn.Module:
        """What the ONNX exporter traces: `contract_module` (this model behind the contract's
        positional inputs) by default. A family whose forward `torch.export` cannot trace (online
        learning calls `torch.autograd.grad`) returns an equivalent module it can trace, e.g.
        `models.online.traced_step(contract_module, example_args)`."""
        return contract_module

    def declaration(self) -> Declaration:
        """What this model declares under the ONNX contract (written into its export)."""
        return Declaration(
            family=self.family,
            config=self.config(),
            buffers=tuple(self.inputs),
            state=tuple(self.state_specs),
            pad_multiple=int(self.pad_multiple),
            note=self.input_note,
            options=tuple(self.runtime_options),
            edge_margin=int(self.edge_margin),
        )


FAMILIES: dict[str, type[DenoiserModel]] = {}


def register_family(cls: type[DenoiserModel]) -> type[DenoiserModel]:
    """Class decorator: make `cls` buildable by its `family` name (models.registry)."""
    if FAMILIES.get(cls.family) is cls:  # the same class again (its module imported twice)
        return cls
    if not cls.family or cls.family in FAMILIES:
        raise ValueError(f"{cls.__name__}: family name {cls.family!r} is empty or taken")
    if cls.config_class.family != cls.family:
        raise ValueError(f"{cls.__name__}: config_class.family must be {cls.family!r}")
    FAMILIES[cls.family] = cls
    return cls


def parameter_count(model: nn.Module) -> int:
    """Number of trainable parameters of a model or one of its parts."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
