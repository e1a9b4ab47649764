"""Threads (docs/reliability.md, "Threads"): instances are independent and may run in
parallel threads; one instance shared by threads serialises their calls (one history)."""

from __future__ import annotations

import sys
import threading
import time

import numpy as np

from rtdenoise.runtime import Denoiser

N = 6


def shot(seed: int) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    normal = np.tile(np.float32([0, 0, 1])[:, None, None], (1, 24, 20))
    return [
        {
            "color": rng.exponential(1.0, (3, 24, 20)).astype(np.float32),
            "albedo": np.full((3, 24, 20), 0.5, np.float32),
            "normal": normal,
            "depth": np.ones((1, 24, 20), np.float32),
            "motion": rng.normal(0, 1, (2, 24, 20)).astype(np.float32),
        }
        for _ in range(N)
    ]


def run_threads(targets) -> list[BaseException]:
    errors: list[BaseException] = []

    def wrap(fn):
        def run():
            try:
                fn()
            except BaseException as exc:
                errors.append(exc)

        return run

    threads = [threading.Thread(target=wrap(t), name=f"t{i}") for i, t in enumerate(targets)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    return errors


def test_two_instances_in_two_threads_equal_sequential_runs():
    shots = [shot(1), shot(2)]
    sequential = []
    for frames in shots:
        den = Denoiser("demo:afn", threads=1)
        sequential.append([den.process(f) for f in frames])
    dens = [Denoiser("demo:afn", threads=1) for _ in shots]
    results: list[list[np.ndarray]] = [[], []]

    def work(k):
        return lambda: results[k].extend(dens[k].process(f) for f in shots[k])

    assert run_threads([work(0), work(1)]) == []
    for got, want in zip(results, sequential, strict=True):
        assert len(got) == N
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)


def test_one_instance_shared_by_threads_serialises_calls():
    den = Denoiser("demo:wskp", threads=1)
    outs: list[np.ndarray] = []
    active, most = [0], [0]
    run = den._run

    def watched(*args):  # widens the window a race would need, and counts overlaps
        active[0] += 1
        most[0] = max(most[0], active[0])
        time.sleep(0.005)
        try:
            return run(*args)
        finally:
            active[0] -= 1

    den._run = watched

    def work(frames):
        return lambda: outs.extend(den.process(f) for f in frames)

    assert run_threads([work(shot(3)), work(shot(4)), work(shot(5))]) == []
    assert den.frames_processed == 3 * N and den.frame_index == 3 * N
    assert all(np.isfinite(o).all() for o in outs) and len(outs) == 3 * N
    assert most[0] == 1  # one frame at a time


def test_a_kernel_failing_in_one_thread_is_raised_in_that_thread_only(monkeypatch):
    monkeypatch.setenv("RTDENOISE_NATIVE_OPS", "0")  # a numba kernel fails (patched below)
    fast_kernel = sys.modules["rtdenoise.runtime.kernels.fast_kernel"]
    original = fast_kernel.FastKernel.compute

    def call(self, *args, **kwargs):
        if threading.current_thread().name == "t0":
            raise ValueError("broken in t0")
        return original(self, *args, **kwargs)

    frames = shot(6)
    want = [Denoiser("demo:wskp", threads=1).process(frames[0])]
    dens = [Denoiser("demo:wskp", threads=1) for _ in range(2)]
    got: list[np.ndarray] = []
    fast_kernel.FastKernel.compute = call
    try:
        errors = run_threads([lambda: dens[0].process(frames[0]),
                              lambda: got.append(dens[1].process(frames[0]))])  # fmt: skip
    finally:
        fast_kernel.FastKernel.compute = original
    assert len(errors) == 1 and "ValueError: broken in t0" in str(errors[0])
    np.testing.assert_array_equal(got[0], want[0])
