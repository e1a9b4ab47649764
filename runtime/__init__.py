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
}

__all__ = [
    "Contract",
    "ContractError",
    "Denoiser",
    "InputError",
    "StateSpec",
    "parse_contract",
    "read_exr",
    "resolve_model",
    "resolve_providers",
    "write_exr",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
