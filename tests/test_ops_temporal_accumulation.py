"""TemporalAccumulation: every form gives all four outputs of the torch form (models.temporal),
the fast kernel to the bit, and the models' opening calls it once per frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from op_forms import session

from rtdenoise.models.ops import TORCH_OPS
from rtdenoise.ops import get_spec
from rtdenoise.runtime.kernels import KERNELS

OP = "TemporalAccumulation"
BRIDGES = ("", "native", "extensions")  # "": the portable function body


def _inputs(shape: tuple[int, int, int, int], seed: int, reset: float = 0.0) -> list[np.ndarray]:
    inputs = get_spec(OP).example_inputs(shape, {}, np.random.default_rng(seed))
    inputs[6] = np.array(reset, np.float32)
    return inputs


@pytest.mark.parametrize("shape", [(1, 3, 13, 17), (2, 1, 8, 6), (1, 3, 32, 48)])
@pytest.mark.parametrize("reset", [0.0, 1.0])
def test_every_form_gives_every_output(shape, reset) -> None:
    inputs = _inputs(shape, sum(shape), reset)
    with torch.no_grad():
        ref = [t.numpy() for t in TORCH_OPS[OP].reference(*map(torch.from_numpy, inputs))]
    blend = ref[1]
    assert 0.0 < (blend < 1.0).mean() < 1.0 or reset  # some pixels keep their history
    assert reset == 0.0 or (blend == 1.0).all()
    feed = dict(zip(get_spec(OP).input_names, inputs, strict=True))
    forms = {
        "numba": KERNELS[OP](*inputs),
        **{
            b or "portable": session(OP, (), b).run(None, feed)
            for b in ("", "native", "extensions")
        },
    }
    for form, outs in forms.items():
        assert len(outs) == 4, form
        for got, want in zip(outs, ref, strict=True):
            assert got.shape == want.shape and got.dtype == np.float32, form
            if form == "portable":  # ORT's own Reproject / ReduceSum arithmetic
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-5, err_msg=form)
            else:
                np.testing.assert_array_equal(got, want, err_msg=form)


def test_nonfinite_history_is_dropped_where_invalid() -> None:
    """An invalid history is selected away, never multiplied by 0: a NaN history leaves the
    pixels that reject it finite (where it is valid it is used, as in the torch form; the
    runtime keeps NaN out of the state, tests/test_guard*.py)."""
    inputs = _inputs((1, 3, 16, 16), 5)
    inputs[4][:, :3] = np.nan  # every accumulated value of the history
    inputs[4][:, 3] = np.maximum(inputs[4][:, 3], 1.0)  # so blend 1 means: rejected
    outs = KERNELS[OP](*inputs)
    fresh = outs[1][:, 0] == 1.0  # the history was rejected
    assert 0 < fresh.mean() < 1
    assert np.isfinite(outs[0].transpose(1, 0, 2, 3)[:, fresh]).all()
    assert np.isnan(outs[0].transpose(1, 0, 2, 3)[:, ~fresh]).all()
    with torch.no_grad():
        ref = TORCH_OPS[OP].reference(*map(torch.from_numpy, inputs))
    for got, want in zip(outs, ref, strict=True):
        np.testing.assert_array_equal(got, want.numpy())
