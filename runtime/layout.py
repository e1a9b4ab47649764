"""Pick a model's conv forms for the CPU it runs on: the `layout.nchwc16` flag.

An exported model may carry a second form of some convs for AVX-512's 16-channel NCHWc block
under `If(layout.nchwc16)` (export/layout_forms.py). The flag is an initializer, False in the
file; ONNX Runtime's constant folding inlines the branch it selects when it loads the model.
Before the session is made, `with_layout` writes True into the model's bytes where ORT's CPU
convs use 16-channel blocks (x86-64 with AVX-512F) and the CPU provider alone runs the model.

`RTDENOISE_NCHWC_BLOCK=8` or `=16` sets the choice by hand (tests run both forms on one
machine).
"""

from __future__ import annotations

import os

from .protobuf import Malformed, fields, length_delimited, rewrite_graph_fields, varint_field

LAYOUT_FLAG = "layout.nchwc16"  # export/layout_forms.py writes it: keep the two names in step
ENV = "RTDENOISE_NCHWC_BLOCK"
_GRAPH_INIT = 5  # GraphProto.initializer
_TENSOR_TYPE, _TENSOR_NAME, _TENSOR_RAW, _BOOL = 2, 8, 9, 9  # TensorProto fields; BOOL = 9


def nchwc_block() -> int:
    """The channel block of ORT's blocked CPU convs here: 16 with AVX-512F, else 8 (or what
    RTDENOISE_NCHWC_BLOCK says)."""
    chosen = os.environ.get(ENV, "").strip()
    if chosen:
        if chosen not in ("8", "16"):
            raise ValueError(f"{ENV}={chosen!r}: expected 8 or 16")
        return int(chosen)
    try:
        from numpy._core._multiarray_umath import __cpu_features__ as features
    except ImportError:  # numpy 1.x
        try:
            from numpy.core._multiarray_umath import __cpu_features__ as features
        except ImportError:
            return 8
    return 16 if features.get("AVX512F") else 8


def has_layout_flag(data: bytes) -> bool:
    """Whether the model's bytes may hold the flag (a fast test before parsing)."""
    return LAYOUT_FLAG.encode() in data


def with_layout(data: bytes, nchwc16: bool) -> bytes | None:
    """The model with its `layout.nchwc16` initializer set to `nchwc16`; None when the main
    graph has no such initializer (or the bytes are not a model)."""
    if not has_layout_flag(data):
        return None
    flag = (
        varint_field(_TENSOR_TYPE, _BOOL)
        + length_delimited(_TENSOR_NAME, LAYOUT_FLAG.encode())
        + length_delimited(_TENSOR_RAW, b"\x01" if nchwc16 else b"\x00")
    )
    try:
        return rewrite_graph_fields(data, _GRAPH_INIT, lambda t: flag if _is_flag(t) else None)
    except Malformed:
        return None


def _is_flag(tensor: memoryview) -> bool:
    return any(
        n == _TENSOR_NAME and isinstance(v, memoryview) and bytes(v) == LAYOUT_FLAG.encode()
        for n, v in fields(tensor)
    )
