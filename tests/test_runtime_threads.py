"""Runtime speed settings: `threads=` reaches both thread pools (ONNX Runtime's intra-op pool and
numba's, which the fast kernels use inside ORT's run), idle ORT workers do not spin next to the
kernels, and small frames run the kernels on one thread (the rule is tested here, not timed:
the threshold itself is measured in benchmarks/, benchmarks/README.md)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rtdenoise.runtime import Denoiser
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.kernels.fast_kernel import FastKernel
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
from rtdenoise.runtime.session import ALLOW_SPINNING, kernel_thread_count

MODEL = "demo:wskp"


@pytest.fixture(autouse=True)
def numba_path(monkeypatch):
    """The numba kernels' thread counts: their path, not the C++ library's (which demo:wskp and
    demo:afn run on by default; its threads: test_native_ops.py)."""
    monkeypatch.setenv("RTDENOISE_NATIVE_OPS", "0")


def frame(den: Denoiser, h: int = 16, w: int = 24, seed: int = 0) -> dict[str, np.ndarray]:
    return synthetic_frames(den.required_buffers, 1, h, w, seed=seed)[0]


@pytest.fixture
def kernel_threads_seen(monkeypatch) -> list[int]:
    """numba's thread count as seen by every fast kernel that ORT calls."""
    seen: list[int] = []
    original = FastKernel.compute  # what both custom-op bridges call

    def call(self, *args, **kwargs):
        seen.append(numba.get_num_threads())
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FastKernel, "compute", call)
    return seen


def test_threads_reach_ort_and_numba(kernel_threads_seen: list[int]) -> None:
    before = numba.get_num_threads()
    den = Denoiser(MODEL, fast_kernels=True, threads=1)
    den.serial_below = 0
    assert den.session.get_session_options().intra_op_num_threads == 1
    den.process(frame(den))
    assert kernel_threads_seen and set(kernel_threads_seen) == {1}
    assert numba.get_num_threads() == before  # restored after the run


def test_threads_above_numbas_pool_are_capped(kernel_threads_seen: list[int]) -> None:
    den = Denoiser(MODEL, fast_kernels=True, threads=numba.config.NUMBA_NUM_THREADS + 3)
    den.serial_below = 0  # the test frame is small
    den.process(frame(den))
    assert set(kernel_threads_seen) == {numba.config.NUMBA_NUM_THREADS}


def test_default_threads_leave_numba_alone(kernel_threads_seen: list[int]) -> None:
    den = Denoiser(MODEL, fast_kernels=True)
    den.serial_below = 0
    den.process(frame(den))
    assert set(kernel_threads_seen) == {numba.get_num_threads()}


def test_numba_threads_are_per_calling_thread() -> None:
    """The context sets numba's (thread-local) count in this thread and restores it."""
    before = numba.get_num_threads()
    with fast_bridge.numba_threads(1):
        assert numba.get_num_threads() == 1
    with fast_bridge.numba_threads(None):
        assert numba.get_num_threads() == before
    assert numba.get_num_threads() == before


def spinning(den: Denoiser) -> str:
    return den.session.get_session_options().get_session_config_entry(ALLOW_SPINNING)


def test_ort_workers_do_not_spin_next_to_the_kernels() -> None:
    assert spinning(Denoiser(MODEL, fast_kernels=True)) == "0"
    assert spinning(Denoiser(MODEL, fast_kernels=True, spinning=True)) == "1"
    assert spinning(Denoiser(MODEL, fast_kernels=False, spinning=False)) == "0"
    with pytest.raises(Exception):  # noqa: B017  ORT's default: the entry is not set
        spinning(Denoiser(MODEL, fast_kernels=False))


def test_serial_rule() -> None:
    """One numba thread below `serial_below` pixels (padded H x W), else `threads`."""
    assert kernel_thread_count((255, 256), None, 256 * 256) == 1
    assert kernel_thread_count((256, 256), None, 256 * 256) is None
    assert kernel_thread_count((256, 256), 2, 256 * 256) == 2
    assert kernel_thread_count((720, 1280), 3) == 3
    assert kernel_thread_count((64, 64), 2) == 1  # the default threshold
    assert kernel_thread_count((1, 1), 2, 0) == 2


def test_small_frames_run_serial_kernels(kernel_threads_seen: list[int]) -> None:
    den = Denoiser(MODEL, fast_kernels=True, threads=2)
    den.process(frame(den))
    assert set(kernel_threads_seen) == {1}
    kernel_threads_seen.clear()
    den.serial_below = 0
    den.process(frame(den, seed=1))
    assert set(kernel_threads_seen) == {min(2, numba.config.NUMBA_NUM_THREADS)}
