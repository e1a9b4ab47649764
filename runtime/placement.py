"""Where a frame's threads run (Linux): the thread that runs the session on one CPU, the fast
kernels' worker threads on the others, as ONNX Runtime places its own workers.

ONNX Runtime pins its intra-op workers to the CPUs after the first and leaves the calling
thread free; numba's OpenMP workers are free too. After an idle gap (a host that renders
between frames) the scheduler often wakes a worker on the caller's CPU, and the frame's
kernels run at one thread's speed until it spreads them again (demo:nbg, 320x240, frames
after a 100 ms pause: 44.2 ms unplaced, 35.5 ms placed, 34.2 ms back to back;
benchmarks/README.md, "Thread placement"). `placed()` pins the caller for the duration of a
run and restores its affinity after; the kernel workers stay pinned, like ONNX Runtime's.
`Denoiser` places threads only where ONNX Runtime pins its own (its default thread count):
processes that share a machine set `threads`, and would otherwise all pin to the same CPUs.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import numpy as np

INTRA_OP_AFFINITIES = "session.intra_op_thread_affinities"  # ORT session config key
_SUPPORTED = hasattr(os, "sched_setaffinity") and hasattr(os, "sched_getaffinity")
_ONE_CALLER = threading.Lock()  # a concurrent caller is left where it is, not stacked on CPU 0
# (calling thread, team size, its CPUs) -> the worker thread ids pinned for it
_placed_teams: dict[tuple[int, int, tuple[int, ...]], list[int]] = {}
_no_thread_ids = False  # set once reading them failed


def worker_cpus(cpus: Sequence[int], count: int) -> list[int]:
    """CPUs for `count` workers of a caller pinned to `cpus[0]`: the others, in turn."""
    others = list(cpus[1:]) or list(cpus)
    return [others[i % len(others)] for i in range(count)]


def ort_thread_affinities(threads: int, cpus: Sequence[int]) -> str | None:
    """`session.intra_op_thread_affinities` that places ONNX Runtime's `threads - 1` workers
    as `worker_cpus` does (1-based processor ids, one per worker); None when there is nothing
    to place. ONNX Runtime places them itself only when it chooses the thread count."""
    if threads < 2 or len(cpus) < 2:
        return None
    return ";".join(str(cpu + 1) for cpu in worker_cpus(sorted(cpus), threads - 1))


def allowed_cpus() -> list[int]:
    """The CPUs the calling thread may run on, sorted ([] where affinity is not supported)."""
    return sorted(os.sched_getaffinity(0)) if _SUPPORTED else []


def _team_worker_ids(team: int) -> list[int]:
    """OS thread ids of the numba workers that serve this thread's parallel kernels ([] where
    they cannot be read: no glibc `gettid`)."""
    global _no_thread_ids
    if _no_thread_ids:
        return []
    try:
        from .kernels._team import team_thread_ids

        ids = np.zeros(team, np.int64)
        team_thread_ids(ids)
    except Exception:  # the symbol is missing (musl, old glibc): the workers stay where they are
        _no_thread_ids = True
        return []
    return [int(t) for t in ids[1:] if t > 0]


def _place_workers(cpus: list[int], team: int) -> None:
    key = (threading.get_ident(), team, tuple(cpus))
    if team < 2 or key in _placed_teams:
        return
    workers = _team_worker_ids(team)
    for tid, cpu in zip(workers, worker_cpus(cpus, len(workers)), strict=True):
        try:
            os.sched_setaffinity(tid, {cpu})
        except OSError:  # the thread has gone, or the host forbids it: leave it be
            pass
    _placed_teams[key] = workers


def release_workers() -> None:
    """Let every worker `placed` pinned run on any allowed CPU again (the next `placed` pins
    them anew): for comparing placed and unplaced runs in one process."""
    every = os.sched_getaffinity(0) if _SUPPORTED else set()
    for workers in _placed_teams.values():
        for tid in workers:
            try:
                os.sched_setaffinity(tid, every)
            except OSError:
                pass
    _placed_teams.clear()


@contextmanager
def placed(team: int | None) -> Iterator[None]:
    """Run the block with the calling thread on its first allowed CPU and the `team - 1`
    numba workers of this thread (`team`: numba's thread count for the run; None: numba's
    current count) on the others. The caller's affinity is restored after. A no-op on one
    CPU, where affinity is not supported, or while another thread is inside `placed`."""
    if not _SUPPORTED or not _ONE_CALLER.acquire(blocking=False):
        yield
        return
    try:
        before = os.sched_getaffinity(0)
        cpus = sorted(before)
        if len(cpus) < 2:
            yield
            return
        if team is None:
            import numba

            team = numba.get_num_threads()
        _place_workers(cpus, team)
        os.sched_setaffinity(0, {cpus[0]})
        try:
            yield
        finally:
            os.sched_setaffinity(0, before)
    finally:
        _ONE_CALLER.release()
