"""AffinityFilter and TemporalAffinityFilter (Isik21 eq. 4, 6-8) beyond the generic spec tests:
every form (torch, ORT portable, ORT fast, numba) against an independent float64 numpy
spelling at the paper's kernel sizes 7, 13 and 19 and dilations 1, 2 and 4 on images smaller
than the footprints (most taps fall outside: weight 0), one portable graph for every k (the
kernel size is an input), the edge cases, and the numba training backward against autograd
of the references."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from op_forms import RTOL, all_forms, assert_forms_agree, rel_err

from rtdenoise.models.ops import TORCH_OPS
from rtdenoise.models.ops.affinity_filter import affinity_filter
from rtdenoise.models.ops.temporal_affinity_filter import temporal_affinity_filter
from rtdenoise.ops import get_spec
from rtdenoise.runtime.kernels import KERNELS

SHAPE = (1, 3, 12, 17)


def numpy_affinity(image, features, bandwidth, centre, k, d, temporal=None):
    """Isik21 eq. (4), (6) (and (7)-(8) with temporal = (previous, previous_features,
    temporal_bandwidth, valid, kt)), pixel by pixel over the taps, in float64."""
    x, f, a, c = (np.asarray(v, np.float64) for v in (image, features, bandwidth, centre))
    n, _, h, w = x.shape
    ys, xs = np.mgrid[0:h, 0:w]
    num, den = np.zeros_like(x), np.zeros_like(a)

    def taps(values, guides, band, size, dil, mask, with_centre):
        r = size // 2
        for i in range(size):
            for j in range(size):
                qy, qx = ys + (i - r) * dil, xs + (j - r) * dil
                inside = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
                qy, qx = qy.clip(0, h - 1), qx.clip(0, w - 1)
                dist = ((f - guides[:, :, qy, qx]) ** 2).sum(axis=1, keepdims=True)
                weight = np.exp(-band * dist) * inside * mask[:, :, qy, qx]
                if with_centre and i == r and j == r:
                    weight = c
                num[...] += weight * values[:, :, qy, qx]
                den[...] += weight

    taps(x, f, a, k, d, np.ones_like(a), True)
    if temporal is not None:
        prev, prev_f, b, valid, kt = temporal
        taps(*(np.asarray(v, np.float64) for v in (prev, prev_f, b)), kt, 1, valid, False)
    return (num / (1e-10 + den)).astype(np.float32)


def _inputs(op: str, k: int, d: int, seed: int, kt: int | None = None) -> list[np.ndarray]:
    spec = get_spec(op)
    inputs = spec.example_inputs(SHAPE, {"dilation": d}, np.random.default_rng(seed))
    inputs[spec.input_names.index("kernel_size")] = np.array(k, np.float32)
    if "temporal_size" in spec.input_names:
        inputs[spec.input_names.index("temporal_size")] = np.array(kt or k, np.float32)
    return inputs


@pytest.mark.parametrize("k", [7, 13, 19])
@pytest.mark.parametrize("d", [1, 2, 4])
def test_affinity_filter_forms_match_numpy(k, d):
    inputs = _inputs("AffinityFilter", k, d, seed=k + d)
    expected = numpy_affinity(*inputs[:4], k, d)
    assert_forms_agree(all_forms("AffinityFilter", inputs, {"dilation": d}), expected)


@pytest.mark.parametrize(("k", "kt", "d"), [(7, 7, 1), (13, 13, 4), (19, 7, 2), (13, 19, 4)])
def test_temporal_affinity_filter_forms_match_numpy(k, kt, d):
    inputs = _inputs("TemporalAffinityFilter", k, d, seed=k + kt + d, kt=kt)
    expected = numpy_affinity(*inputs[:4], k, d, temporal=(*inputs[4:8], kt))
    assert_forms_agree(all_forms("TemporalAffinityFilter", inputs, {"dilation": d}), expected)


def test_kernel_size_changes_the_result_and_out_of_image_taps_weigh_zero():
    small = _inputs("AffinityFilter", 7, 1, seed=3)
    large = _inputs("AffinityFilter", 19, 1, seed=3)
    out7, out19 = (KERNELS["AffinityFilter"](*x, dilation=1) for x in (small, large))
    assert np.isfinite(out7).all() and float(np.abs(out7 - out19).max()) > 1e-2
    # a 1 x 1 image: every tap but the centre lies outside, so out = image for any k and c > 0
    one = [x[:, :, :1, :1].copy() if x.ndim == 4 else x for x in large]
    for form, out in all_forms("AffinityFilter", one, {"dilation": 4}).items():
        np.testing.assert_allclose(out, one[0], rtol=1e-6, err_msg=form)


def test_without_valid_history_the_temporal_filter_is_the_spatial_one():
    inputs = _inputs("TemporalAffinityFilter", 13, 4, seed=5)
    inputs[7] = np.zeros_like(inputs[7])  # valid = 0: omega = 0 (Isik21: t = 0)
    inputs[4] = np.full_like(inputs[4], 1e6)  # whatever the previous output holds
    spatial = KERNELS["AffinityFilter"](*inputs[:4], inputs[8], dilation=4)
    for form, out in all_forms("TemporalAffinityFilter", inputs, {"dilation": 4}).items():
        assert rel_err(out, spatial) <= RTOL, form


@pytest.mark.parametrize("size", [4.0, 0.0, 7.5, 65.0])
def test_invalid_kernel_sizes_are_refused(size):
    inputs = _inputs("AffinityFilter", 7, 1, seed=0)
    inputs[4] = np.array(size, np.float32)
    with pytest.raises(ValueError, match="kernel size must be an odd integer"):
        KERNELS["AffinityFilter"](*inputs, dilation=1)
    with pytest.raises(ValueError, match="kernel size must be an odd integer"):
        TORCH_OPS["AffinityFilter"](*[torch.from_numpy(x) for x in inputs], dilation=1)


@pytest.mark.parametrize("op", ["AffinityFilter", "TemporalAffinityFilter"])
def test_training_backward_matches_autograd_of_the_reference(op):
    """The numba forward / backward the model trains with (models.ops.affinity_autograd)."""
    inputs = _inputs(op, 5, 2, seed=11, kt=3)
    inputs = [x[:, :, :9, :11].copy() if x.ndim == 4 else x for x in inputs]
    public = affinity_filter if op == "AffinityFilter" else temporal_affinity_filter
    names = get_spec(op).input_names
    grads = []
    for fn in (TORCH_OPS[op].reference, public):
        tensors = [
            torch.from_numpy(x.copy()).requires_grad_(x.ndim == 4 and n != "valid")
            for x, n in zip(inputs, names, strict=True)
        ]
        out = fn(*tensors, dilation=2)
        weights = torch.linspace(-1.0, 1.0, out.numel()).reshape(out.shape)
        (out * weights).sum().backward()
        grads.append([t.grad for t in tensors if t.requires_grad])
        assert out.shape == tensors[0].shape
    assert len(grads[0]) == len(grads[1]) == (4 if op == "AffinityFilter" else 7)
    for ref, fast in zip(*grads, strict=True):
        scale = max(1.0, float(ref.abs().max()))
        assert float((ref - fast).abs().max()) / scale < 1e-4
