"""`fast_kernel`: the fast form of a custom op from its spec and one numba driver.

    @fast_kernel("KernelApply")
    def kernel_apply(image, kernel, out, kernel_size, dilation): ...   # fills `out`

The driver receives the inputs as C-contiguous float32 arrays, already checked against the
op's spec (rtdenoise.ops), then one preallocated float32 array per output (shapes from the
spec's rule), then the int attributes as keywords; it fills the outputs in place. The
resulting `FastKernel` is what `rtdenoise.runtime.bridge.extensions` registers with ONNX Runtime and
what tests and benchmarks call directly. No torch here.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rtdenoise.ops import OpSpec
from rtdenoise.ops.spec import form_decorator

Driver = Callable[..., None]
WARMUP_SHAPE = (1, 1, 4, 6)  # tiny image: compiles (or loads from numba's cache) every kernel


def as_f32c(a: np.ndarray) -> np.ndarray:
    """`a` as a writable C-contiguous float32 array (one numba specialisation per kernel)."""
    a = np.asarray(a)
    if a.dtype != np.float32 or not a.flags.c_contiguous or not a.flags.writeable:
        a = np.array(a, dtype=np.float32, order="C", copy=True)
    return a


@dataclass(frozen=True)
class FastKernel:
    """One op's fast form: `kernel(*inputs, *attrs)` or `kernel(*inputs, **attrs)` -> output
    array (a tuple if several)."""

    spec: OpSpec
    driver: Driver

    @property
    def name(self) -> str:
        return self.spec.name

    def __call__(
        self, *args: np.ndarray | int, **attrs: int
    ) -> np.ndarray | tuple[np.ndarray, ...]:
        inputs, values = self.spec.split_args(args, attrs)
        arrays = [as_f32c(a) for a in inputs]
        self.spec.validate_call([a.shape for a in arrays], values)
        shapes = self.spec.output_shapes([a.shape for a in arrays], values)
        outs = tuple(np.empty(tuple(int(d) for d in s), np.float32) for s in shapes)
        self.compute(arrays, outs, values)
        return outs if len(outs) > 1 else outs[0]

    def compute(
        self, inputs: Sequence[np.ndarray], outs: Sequence[np.ndarray], attrs: dict[str, int]
    ) -> None:
        """Fill `outs` (C-contiguous float32, the spec's shapes) from checked `inputs`: the
        driver, or zeros when some array is empty. Both custom-op bridges call this."""
        if all(a.size for a in (*inputs, *outs)):
            self.driver(*inputs, *outs, **attrs)
        else:  # an empty input or output: nothing to compute
            for o in outs:
                o.fill(0.0)

    def warmup(self) -> None:
        """Compile (or load from numba's cache) the kernel on a tiny valid input."""
        attrs = self.spec.attr_sets()[0]
        self(*self.spec.example_inputs(WARMUP_SHAPE, attrs, np.random.default_rng(0)), **attrs)


KERNELS: dict[str, FastKernel] = {}


# Decorator: a numba driver (inputs, outputs, int attributes) -> the op's FastKernel.
fast_kernel = form_decorator(KERNELS, "fast kernel", FastKernel)
