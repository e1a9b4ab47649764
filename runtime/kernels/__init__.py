"""Fast (numba) kernels of the custom ops: one module per op (named like its spec in
rtdenoise.ops). No torch.

Importing this package imports every module, which registers each op's `FastKernel` in
`KERNELS`; `rtdenoise.runtime.bridge.extensions` registers them all with ONNX Runtime. See
docs/architecture.md, "Adding an op".
"""

from __future__ import annotations

from pathlib import Path

from rtdenoise.ops import import_submodules, plugins

from .cache import clear_if_sources_changed
from .fast_kernel import KERNELS, FastKernel, fast_kernel

clear_if_sources_changed(Path(__file__).parent)  # before any kernel loads numba's cache
import_submodules(__name__)
plugins.load_modules(plugins.KERNELS)  # forms of other packages' ops (docs/your-own-model.md)


def warmup() -> None:
    """Compile or load every kernel now (first call in a fresh process otherwise pays it)."""
    for kernel in KERNELS.values():
        kernel.warmup()


__all__ = ["KERNELS", "FastKernel", "fast_kernel", "warmup"]
