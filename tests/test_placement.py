"""Thread placement (`rtdenoise.runtime.placement`): the rules are pure and tested here; that a
run pins the caller to one CPU, the kernel workers to the others, and gives the caller its
affinity back (also after a failed frame) is checked on the live threads. Its speed effect is
measured in benchmarks/, not timed here."""

from __future__ import annotations

import os
import threading

import numba
import numpy as np
import pytest

from rtdenoise.runtime import placement
from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.kernels.fast_kernel import FastKernel
from rtdenoise.runtime.sequences.synthetic import synthetic_frames

CPUS = placement.allowed_cpus()
multi_cpu = pytest.mark.skipif(len(CPUS) < 2, reason="needs thread affinity and two CPUs")


@pytest.fixture(autouse=True)
def numba_path(monkeypatch):
    """The numba kernels' thread placement: their path, not the C++ library's (which demo:wskp and
    demo:afn run on by default; its threads: test_native_ops.py)."""
    monkeypatch.setenv("RTDENOISE_NATIVE_OPS", "0")


def affinity_of(tid: int) -> set[int]:
    return os.sched_getaffinity(tid)


def test_workers_go_to_every_cpu_but_the_callers_in_turn() -> None:
    assert placement.worker_cpus([0, 1], 1) == [1]
    assert placement.worker_cpus([0, 1, 2, 3], 5) == [1, 2, 3, 1, 2]
    assert placement.worker_cpus([4, 6, 9], 2) == [6, 9]
    assert placement.worker_cpus([3], 2) == [3, 3]  # one CPU: nothing to spread over


def test_ort_affinities_are_one_based_one_per_worker() -> None:
    assert placement.ort_thread_affinities(3, [0, 1, 2, 3]) == "2;3"
    assert placement.ort_thread_affinities(4, [1, 0]) == "2;2;2"
    assert placement.ort_thread_affinities(1, [0, 1]) is None  # no workers
    assert placement.ort_thread_affinities(4, [0]) is None  # one CPU


@multi_cpu
def test_placed_pins_caller_and_workers_then_restores_the_caller() -> None:
    before, threads = os.sched_getaffinity(0), numba.get_num_threads()
    numba.set_num_threads(2)
    try:
        with placement.placed(2):
            assert os.sched_getaffinity(0) == {CPUS[0]}
            workers = placement._team_worker_ids(2)
    finally:
        numba.set_num_threads(threads)
    assert os.sched_getaffinity(0) == before
    assert workers, "numba's worker thread was not found"
    assert all(affinity_of(t) == {CPUS[1]} for t in workers)


@multi_cpu
def test_a_concurrent_caller_is_left_where_it_is() -> None:
    inside, release, seen = threading.Event(), threading.Event(), {}

    def first() -> None:
        with placement.placed(1):
            inside.set()
            release.wait(10)

    t = threading.Thread(target=first)
    t.start()
    inside.wait(10)
    before = os.sched_getaffinity(0)
    with placement.placed(1):
        seen["during"] = os.sched_getaffinity(0)
    release.set()
    t.join()
    assert seen["during"] == before  # not stacked onto the first caller's CPU


@multi_cpu
def test_denoiser_restores_the_callers_affinity_after_good_and_failed_frames(monkeypatch) -> None:
    before = os.sched_getaffinity(0)
    den = Denoiser("demo:wskp", threads=2, pin_threads=True)
    frames = synthetic_frames(den.required_buffers, 2, 16, 24)
    den.process(frames[0])
    assert os.sched_getaffinity(0) == before

    def broken(self, *args, **kwargs):
        raise ValueError("broken kernel")

    monkeypatch.setattr(FastKernel, "compute", broken)  # fails inside the session run
    with pytest.raises(Exception, match="broken kernel"):  # as the kernel error it becomes
        den.process(frames[1])
    assert os.sched_getaffinity(0) == before


@multi_cpu
@pytest.mark.parametrize(
    ("options", "pinned"),
    [({}, True), ({"threads": 2}, False), ({"threads": 2, "pin_threads": True}, True),
     ({"pin_threads": False}, False)],
)  # fmt: skip
def test_pinned_by_default_only_where_ort_places_its_own_workers(
    monkeypatch, options: dict, pinned: bool
) -> None:
    """threads=None: ORT pins its workers, the run pins the caller to match; threads=N (a
    process sharing the machine, e.g. a cluster task): nothing is pinned unless asked."""
    seen: list[set[int]] = []
    original = FastKernel.compute  # runs on the thread that called process()

    def call(self, *args, **kwargs):
        seen.append(os.sched_getaffinity(0))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FastKernel, "compute", call)
    den = Denoiser("demo:wskp", **options)
    den.process(synthetic_frames(den.required_buffers, 1, 16, 24)[0])
    assert seen
    want = {CPUS[0]} if pinned else set(CPUS)
    assert all(s == want for s in seen)


def test_pinning_changes_no_numbers() -> None:
    dens = [Denoiser("demo:nbg", threads=2, pin_threads=p) for p in (False, True)]
    frames = synthetic_frames(dens[0].required_buffers, 3, 270, 260)  # parallel kernels
    for f in frames:
        a, b = (d.process(f) for d in dens)
        np.testing.assert_array_equal(a, b)
