"""Runtime speed settings: `threads=` reaches both thread pools (ONNX Runtime's intra-op pool and
numba's, which the fast kernels use inside ORT's run), idle ORT workers do not spin next to the
kernels, and fast_kernels="auto" picks the fast or the portable session by frame size (the
rule is tested, not timed: the threshold itself is measured in benchmarks/)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from rtdenoise.runtime import fastops
from rtdenoise.runtime.denoiser import ALLOW_SPINNING, Denoiser, use_fast_kernels
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.kernels.fast_kernel import FastKernel
from rtdenoise.runtime.synthetic import synthetic_frames

MODEL = "demo:wskp"


def frame(den: Denoiser, h: int = 16, w: int = 24, seed: int = 0) -> dict[str, np.ndarray]:
    return synthetic_frames(den.required_buffers, 1, h, w, seed=seed)[0]


@pytest.fixture
def kernel_threads(monkeypatch) -> list[int]:
    """numba's thread count as seen by every fast kernel that ORT calls."""
    seen: list[int] = []
    original = FastKernel.__call__

    def call(self, *args, **kwargs):
        seen.append(numba.get_num_threads())
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FastKernel, "__call__", call)
    return seen


def test_threads_reach_ort_and_numba(kernel_threads: list[int]) -> None:
    before = numba.get_num_threads()
    den = Denoiser(MODEL, fast_kernels=True, threads=1)
    assert den.session.get_session_options().intra_op_num_threads == 1
    den.process(frame(den))
    assert kernel_threads and set(kernel_threads) == {1}
    assert numba.get_num_threads() == before  # restored after the run


def test_threads_above_numbas_pool_are_capped(kernel_threads: list[int]) -> None:
    den = Denoiser(MODEL, fast_kernels=True, threads=numba.config.NUMBA_NUM_THREADS + 3)
    den.process(frame(den))
    assert set(kernel_threads) == {numba.config.NUMBA_NUM_THREADS}


def test_default_threads_leave_numba_alone(kernel_threads: list[int]) -> None:
    den = Denoiser(MODEL, fast_kernels=True)
    den.process(frame(den))
    assert set(kernel_threads) == {numba.get_num_threads()}


def test_numba_threads_are_per_calling_thread() -> None:
    """numba's setting is thread-local: the context sets it in the thread that runs."""
    before = numba.get_num_threads()
    with fastops.kernel_threads(1):
        assert numba.get_num_threads() == 1
    with fastops.kernel_threads(None):
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


def test_auto_rule() -> None:
    assert use_fast_kernels((240, 320), 240 * 320)
    assert not use_fast_kernels((240, 320), 240 * 320 + 1)
    assert use_fast_kernels((1, 1), 0)


def test_auto_picks_the_session_by_frame_size() -> None:
    den = Denoiser(MODEL, fast_kernels="auto", fast_min_pixels=20 * 24)
    fast = Denoiser(MODEL, fast_kernels=True)
    small, large = frame(den, 16, 24), frame(den, 20, 24, seed=1)
    calls = sum(fastops.CALLS.values())
    out_small = den.process(small)
    assert den.kernel_path == "portable" and sum(fastops.CALLS.values()) == calls
    out_large = den.process(large)  # a size change starts a new history
    assert den.kernel_path == "fast" and sum(fastops.CALLS.values()) > calls
    np.testing.assert_allclose(out_large, fast.process(large), rtol=1e-4, atol=1e-5)
    fast.reset()
    np.testing.assert_allclose(out_small, fast.process(small), rtol=1e-4, atol=1e-5)
    assert den.process(small) is not None and den.kernel_path == "portable"


def test_explicit_paths_ignore_the_threshold() -> None:
    den = Denoiser(MODEL, fast_kernels=True, fast_min_pixels=10**9)
    den.process(frame(den))
    assert den.kernel_path == "fast"
    den = Denoiser(MODEL, fast_kernels=False, fast_min_pixels=0)
    den.process(frame(den))
    assert den.kernel_path == "portable" and den.fast_kernels is False


def test_bad_fast_kernels_value() -> None:
    with pytest.raises(InputError, match="fast_kernels"):
        Denoiser(MODEL, fast_kernels="yes")
