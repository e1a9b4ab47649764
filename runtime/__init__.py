"""rtdenoise.runtime: run exported denoisers with ONNX Runtime. Never imports torch.

Three wings (docs/architecture.md, "Runtime"): this package is what a host embeds (`Denoiser`
in `denoiser.py`, with `session`, `state`, `arrays`, `guard`, `contract`, `errors`);
`bridge/` is how ONNX Runtime reaches the fast kernels of `kernels/`; `sequences/` is the EXR
sequence tooling around them (`denoise-run`, compare, metrics). Public names are imported
lazily, so `import rtdenoise.runtime` stays cheap until one is used.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

from .errors import InputError

if TYPE_CHECKING:
    from .contract import Contract, ContractError, StateSpec, parse_contract
    from .denoiser import Denoiser
    from .sequences.exr import read_exr, write_exr
    from .sequences.frames import Frame, find_frames, iter_sequence, read_frame, write_output
    from .sequences.layouts import Layout, get_layout, load_layout
    from .session import resolve_model, resolve_providers

_LAZY = {
    "Denoiser": ".denoiser",
    "resolve_model": ".session",
    "resolve_providers": ".session",
    "Contract": ".contract",
    "ContractError": ".contract",
    "StateSpec": ".contract",
    "parse_contract": ".contract",
    "read_exr": ".sequences.exr",
    "write_exr": ".sequences.exr",
    "Layout": ".sequences.layouts",
    "get_layout": ".sequences.layouts",
    "load_layout": ".sequences.layouts",
    "Frame": ".sequences.frames",
    "find_frames": ".sequences.frames",
    "iter_sequence": ".sequences.frames",
    "read_frame": ".sequences.frames",
    "write_output": ".sequences.frames",
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
