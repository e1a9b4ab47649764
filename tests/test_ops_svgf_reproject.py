"""SvgfReproject (crossreg's history warp) in every form agrees with its torch form to the bit:
crossreg's state carries the warp from frame to frame, so the op must not change what the
graph it replaced computed (the torch form is that graph's spelling). Also: what the tests
accept and reject on a hand-made history."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from op_forms import all_forms, native_cpp_holds, session

from rtdenoise.models.ops import TORCH_OPS
from rtdenoise.ops import get_spec
from rtdenoise.runtime.kernels import KERNELS

SPEC = get_spec("SvgfReproject")


def _torch(inputs, attrs):
    with torch.no_grad():
        out = TORCH_OPS["SvgfReproject"].reference(*map(torch.from_numpy, inputs), **attrs)
    return [o.numpy() for o in out]


@pytest.mark.parametrize("attrs", SPEC.example_attrs)
@pytest.mark.parametrize("shape", [(1, 9, 13, 17), (2, 3, 8, 6), (1, 9, 48, 64), (1, 1, 2, 5)])
def test_every_form_is_the_torch_form_to_the_bit(shape, attrs):
    inputs = SPEC.example_inputs(shape, attrs, np.random.default_rng(sum(shape)))
    ref = _torch(inputs, attrs)
    if shape[2] > 2:
        assert 0.2 < ref[1].mean() < 1  # some pixels rejected, some kept
    feed = dict(zip(SPEC.input_names, inputs, strict=True))
    forms = {"numba": KERNELS["SvgfReproject"](*inputs, **attrs)}
    key = tuple(sorted(attrs.items()))
    forms["portable"] = session("SvgfReproject", key, "").run(None, feed)
    forms["ort_fast"] = session("SvgfReproject", key, "native").run(None, feed)
    if native_cpp_holds("SvgfReproject"):
        forms["native_cpp"] = session("SvgfReproject", key, "native-cpp").run(None, feed)
    for form, outs in forms.items():
        for name, out, expected in zip(SPEC.output_names, outs, ref, strict=True):
            np.testing.assert_array_equal(out, expected, err_msg=f"{form} {name}")


def test_still_history_is_kept_and_a_new_surface_rejected():
    """No motion, the same geometry: the history comes back as it was, valid everywhere; a
    block whose previous depth is far off is rejected in every form: the 3 x 3 fallback lends
    the block's rim the passing pixels beside it, its core has none, and the erosion of the
    core takes the rim back, so exactly the block is dropped."""
    h, w = 10, 12
    rng = np.random.default_rng(3)
    previous = rng.random((1, 3, h, w), dtype=np.float32)
    normal = np.zeros((1, 3, h, w), np.float32)
    normal[:, 2] = 1.0
    depth = np.full((1, 1, h, w), 2.0, np.float32)
    geometry = np.concatenate([normal, depth], axis=1)
    geometry[:, 3, 3:7, 4:8] = 9.0
    motion = np.zeros((1, 2, h, w), np.float32)
    scalars = [np.array(10.0, np.float32), np.array(4.0, np.float32)]
    inputs = [previous, geometry, motion, normal, depth, *scalars]
    expected_mask = np.ones((h, w), np.float32)
    expected_mask[3:7, 4:8] = 0.0
    for form, out in all_forms("SvgfReproject", inputs, {"fallback": 1, "erode": 1}).items():
        np.testing.assert_array_equal(out[0], previous[0] * expected_mask, err_msg=form)
