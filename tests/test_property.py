"""Property-based: whatever a frame holds (NaN, Inf, huge, negative, any size, sizes that
change), `Denoiser.process` returns a finite, non-negative (3, H, W) image, leaves the caller's
arrays alone, counts every pixel with NaN/Inf, and nothing non-finite reaches the model (its
state and output never need the last-resort replacement), on both paths of every demo model."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rtdenoise.runtime import Denoiser

CHANNELS = {"color": 3, "color_b": 3, "albedo": 3, "normal": 3, "depth": 1, "motion": 2}
SPECIAL = [np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-30, 1e4, 1e6, 1e30, 3e38, -3e38]
VALUES = st.one_of(
    st.sampled_from(SPECIAL), st.floats(width=32, allow_nan=True, allow_infinity=True)
)


@st.composite
def frames(draw) -> list[dict[str, np.ndarray]]:
    """1-3 frames: plausible random buffers (seeded), with drawn values written over drawn
    pixels, whole buffers or channels; the size may change from one frame to the next."""
    out = []
    for _ in range(draw(st.integers(1, 3))):
        h, w = draw(st.integers(1, 20)), draw(st.integers(1, 20))
        rng = np.random.default_rng(draw(st.integers(0, 2**16)))
        scale = draw(st.sampled_from([1e-3, 1.0, 1e3]))
        b = {
            "color": scale * rng.exponential(1.0, (3, h, w)),
            "color_b": scale * rng.exponential(1.0, (3, h, w)),
            "albedo": rng.random((3, h, w)),
            "normal": rng.uniform(-1, 1, (3, h, w)),
            "depth": rng.uniform(0.1, 100, (1, h, w)),
            "motion": rng.normal(0, 3, (2, h, w)),
        }
        b = {k: v.astype(np.float32) for k, v in b.items()}
        for _ in range(draw(st.integers(0, 6))):
            name = draw(st.sampled_from(list(CHANNELS)))
            value = draw(VALUES)
            where = draw(st.sampled_from(["pixel", "channel", "all"]))
            if where == "pixel":
                b[name][:, draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))] = value
            elif where == "channel":
                b[name][draw(st.integers(0, CHANNELS[name] - 1))] = value
            else:
                b[name][:] = value
        out.append(b)
    return out


_DENOISERS: dict[tuple[str, bool], Denoiser] = {}


def denoiser(model: str, fast: bool) -> Denoiser:
    if (model, fast) not in _DENOISERS:
        _DENOISERS[(model, fast)] = Denoiser(model, fast_kernels=fast, threads=1)
    return _DENOISERS[(model, fast)]


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "portable"])
@pytest.mark.parametrize("model", ["demo:afn", "demo:wskp", "demo:nbg", "demo:crossreg"])
def test_any_frame_gives_a_finite_image_and_history(model, fast):
    den = denoiser(model, fast)
    assert den.fast_kernels is fast

    @settings(
        max_examples=15,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(frames())
    def check(sequence):
        for b in sequence:
            given_arrays = {k: v.copy() for k, v in b.items()}
            with np.errstate(all="ignore"):
                out = den.process(b)
            h, w = b["color"].shape[1:]
            assert out.shape == (3, h, w) and out.dtype == np.float32
            assert np.isfinite(out).all() and (out >= 0).all()
            for k, v in b.items():
                np.testing.assert_array_equal(v, given_arrays[k])
            for s in den.state_specs:
                assert np.isfinite(den.state_value(s.name)).all()
            bad = np.zeros((h, w), bool)
            for name in den.required_buffers:
                bad |= ~np.isfinite(b[name]).all(axis=0)
            assert den.last_nonfinite == int(bad.sum())
            assert den.last_state_nonfinite == 0 and den.last_guard.output_nonfinite == 0

    check()
