"""Fast (numba) kernels of the rtdenoise custom ops (design.md s.2, form 3). No torch.

Adding an op: a new module with NAME, INT_ATTRS, the kernel function and `warmup`, and one
line in `KERNELS`. `rtdenoise.runtime.fastops` registers every entry with ONNX Runtime.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import adaptive_fusion, kernel_apply, kernel_fusion, weight_sharing_filter


@dataclass(frozen=True)
class KernelDef:
    """One fast kernel: fn(*float32 inputs, **int attributes) -> float32 output."""

    name: str
    fn: Callable[..., np.ndarray]
    n_inputs: int
    int_attrs: tuple[str, ...]
    warmup: Callable[[], None]


KERNELS: dict[str, KernelDef] = {
    kernel_apply.NAME: KernelDef(
        kernel_apply.NAME, kernel_apply.kernel_apply, 2, kernel_apply.INT_ATTRS, kernel_apply.warmup
    ),
    adaptive_fusion.NAME: KernelDef(
        adaptive_fusion.NAME,
        adaptive_fusion.adaptive_fusion,
        3,
        adaptive_fusion.INT_ATTRS,
        adaptive_fusion.warmup,
    ),
    weight_sharing_filter.NAME: KernelDef(
        weight_sharing_filter.NAME,
        weight_sharing_filter.weight_sharing_filter,
        2,
        weight_sharing_filter.INT_ATTRS,
        weight_sharing_filter.warmup,
    ),
    kernel_fusion.NAME: KernelDef(
        kernel_fusion.NAME,
        kernel_fusion.kernel_fusion,
        2,
        kernel_fusion.INT_ATTRS,
        kernel_fusion.warmup,
    ),
}


def warmup() -> None:
    """Compile or load every kernel now (first call in a fresh process otherwise pays it)."""
    for k in KERNELS.values():
        k.warmup()


__all__ = ["KERNELS", "KernelDef", "warmup"]
