"""rtdenoise.models: the denoisers in PyTorch, and the public API a family of your own uses
(docs/your-own-model.md).

What a family declares (`DenoiserModel`): `family` (its name), `config_class` (a frozen
`FamilyConfig` dataclass, JSON-able), `example_config` (small, fast on a CPU), `inputs` (the
canonical buffers it reads: `BUFFER_CHANNELS`), `state_specs` (its temporal tensors:
`StateSpec`), `pad_multiple`, `input_note`, `forward(buffers, state, reset) -> (output,
next_state)`, optionally `loss` (its paper's), `runtime_options` (`add_runtime_option`) and
`export_module`. It registers with `@register_family` and joins through an entry point of group
`rtdenoise.families`. `API_VERSION` is the ONNX contract's version: this API changes only with
the contract (runtime/contract.py).
"""

from rtdenoise.runtime.contract import (
    BUFFER_CHANNELS,
    CONTRACT_VERSION,
    RuntimeOption,
    StateSpec,
)

from .accumulation import (
    ACCUMULATION_INPUTS,
    ACCUMULATION_NOTE,
    ACCUMULATION_STATE,
    AccumulatingConfig,
    demodulate_and_accumulate,
)
from .base import DenoiserModel, FamilyConfig, parameter_count, register_family
from .checkpoint import load_checkpoint, save_checkpoint
from .losses import smape, temporal_smape
from .registry import build_model, families, family_class, family_source, load_family_module

API_VERSION = CONTRACT_VERSION

__all__ = [
    "ACCUMULATION_INPUTS",
    "ACCUMULATION_NOTE",
    "ACCUMULATION_STATE",
    "API_VERSION",
    "BUFFER_CHANNELS",
    "AccumulatingConfig",
    "DenoiserModel",
    "FamilyConfig",
    "RuntimeOption",
    "StateSpec",
    "build_model",
    "demodulate_and_accumulate",
    "families",
    "family_class",
    "family_source",
    "load_checkpoint",
    "load_family_module",
    "parameter_count",
    "register_family",
    "save_checkpoint",
    "smape",
    "temporal_smape",
]
