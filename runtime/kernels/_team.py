"""OS thread ids of numba's worker threads, for `rtdenoise.runtime.placement` (no torch)."""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange, types

_gettid = types.ExternalFunction("gettid", types.int32())  # glibc >= 2.30, resolved by name


@njit(parallel=True, cache=True)
def team_thread_ids(out: np.ndarray) -> None:
    """out[k] = the OS thread id of team thread k (0: the caller) of this thread's next
    parallel region; out has numba's current thread count of slots."""
    for _ in prange(out.shape[0] * 64):  # every team thread gets iterations
        out[numba.get_thread_id()] = _gettid()
