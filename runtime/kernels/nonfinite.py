"""Non-finite inputs of a fast kernel: NaN outputs, never an exception.

The kernels are compiled with fastmath (no NaN/Inf assumed), so a NaN or Inf that a broken
model produces (NaN weights, an overflow) can turn into a division by zero inside numba
(ZeroDivisionError, seen as "SystemError: CPUDispatcher ... returned a result with an
exception set") or into finite garbage that would enter the temporal history. The portable
bodies propagate NaN instead, and the Denoiser's recovery keys on it (output zeroed and
counted, state zeroed, the next frame a new history). `nan_on_nonfinite` gives a driver that
behaviour: before the kernel runs, one vectorised pass per input (a float32 sum, which is
finite only when every element is; the exact test only when it is not, e.g. on overflow);
a non-finite input fills every output with NaN instead of running the kernel. An op whose
inputs only meet multiplications and additions on their way to the output (KernelFusion's
images) may leave those to the hardware's NaN propagation: `inputs=` names the ones checked
before, and the outputs (smaller) are checked after.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np


def all_finite(a: np.ndarray) -> bool:
    """True when no element of `a` is NaN or +-Inf (one pass when true)."""
    if a.size == 0:
        return True
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.add.reduce(a, axis=None, dtype=np.float32)):
            return True
    return bool(np.isfinite(a).all())  # the sum overflowed, or there is a NaN/Inf


def nan_on_nonfinite(
    n_inputs: int, inputs: tuple[int, ...] | None = None
) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Decorator for a driver `(*inputs, *outputs, **attrs)` with `n_inputs` inputs: outputs
    all NaN, kernel not run, when some input holds NaN/Inf. inputs: check only these inputs
    before the kernel and every output after it (None: every input, before)."""
    before = tuple(range(n_inputs)) if inputs is None else inputs

    def wrap(driver: Callable[..., None]) -> Callable[..., None]:
        @functools.wraps(driver)
        def guarded(*arrays: np.ndarray, **attrs: int) -> None:
            outs = arrays[n_inputs:]
            if all(all_finite(arrays[i]) for i in before):
                driver(*arrays, **attrs)
                if inputs is None or all(all_finite(o) for o in outs):
                    return
            for out in outs:
                out.fill(np.nan)

        return guarded

    return wrap


__all__ = ["all_finite", "nan_on_nonfinite"]
