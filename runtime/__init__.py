"""rtdenoise.runtime: run exported denoisers with ONNX Runtime. Never imports torch.

Public names are imported lazily, so `import rtdenoise.runtime` stays cheap until one is used.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from .errors import InputError

if TYPE_CHECKING:
    from .contract import Contract, ContractError, StateSpec, parse_contract
    from .denoiser import Denoiser, resolve_model, resolve_providers
    from .exr import read_exr, write_exr
    from .layouts import Layout, get_layout, load_layout
    from .sequence import Frame, find_frames, iter_sequence, read_frame, write_output

_LAZY = {
    "Denoiser": ".denoiser",
    "resolve_model": ".denoiser",
    "resolve_providers": ".denoiser",
    "Contract": ".contract",
    "ContractError": ".contract",
    "StateSpec": ".contract",
    "parse_contract": ".contract",
    "read_exr": ".exr",
    "write_exr": ".exr",
    "Layout": ".layouts",
    "get_layout": ".layouts",
    "load_layout": ".layouts",
    "Frame": ".sequence",
    "find_frames": ".sequence",
    "iter_sequence": ".sequence",
    "read_frame": ".sequence",
    "write_output": ".sequence",
}

__all__ = [
    "Contract",
    "ContractError",
    "Denoiser",
    "Frame",
    "InputError",
    "Layout",
    "StateSpec",
    "find_frames",
    "get_layout",
    "iter_sequence",
    "load_layout",
    "parse_contract",
    "read_exr",
    "read_frame",
    "resolve_model",
    "resolve_providers",
    "write_exr",
    "write_output",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
