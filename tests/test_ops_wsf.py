"""WeightSharingFilter and KernelFusion (Fan21) in their three forms: torch reference == ONNX
function body (ORT, portable) == fast kernel (ORT with the numba kernels, and called directly)
== an independent numpy spelling; gradients of the torch forms; export of a tiny model.
"""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from op_forms import RTOL, all_forms, assert_forms_agree, rel_err
from torch import nn

from rtdenoise.export import ops as eops
from rtdenoise.export.onnx_export import to_onnx
from rtdenoise.export.op_bench import bench_op
from rtdenoise.models.ops.kernel_fusion import kernel_fusion
from rtdenoise.models.ops.weight_sharing_filter import weight_sharing_filter
from rtdenoise.ops import get_spec
from rtdenoise.ops.weight_sharing_filter import attrs_to_sizes, sizes_to_attrs
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.kernels import KERNELS

FAN21 = {"size_min": 3, "size_step": 2, "count": 6}  # sizes 3, 5, ..., 13


# ------------------------------------------------------------------- WeightSharingFilter


def wsf_numpy(image: np.ndarray, weights: np.ndarray, sizes: list[int]) -> np.ndarray:
    """Brute force in float64: explicit clipped windows, sum(w x) / sum(w), 0 where sum(w) = 0."""
    n, c, h, w = image.shape
    image, weights = image.astype(np.float64), weights.astype(np.float64)
    out = np.zeros((n, len(sizes) * c, h, w))
    for i, s in enumerate(sizes):
        r = s // 2
        for y in range(h):
            y0, y1 = max(0, y - r), min(h, y + r + 1)
            for x in range(w):
                x0, x1 = max(0, x - r), min(w, x + r + 1)
                wins = weights[:, i, y0:y1, x0:x1]
                den = wins.sum(axis=(1, 2))
                num = (wins[:, None] * image[:, :, y0:y1, x0:x1]).sum(axis=(2, 3))
                ok = den > 0
                out[:, i * c : (i + 1) * c, y, x] = np.where(
                    ok[:, None], num / np.where(ok, den, 1.0)[:, None], 0.0
                )
    return out


WSF_CASES = [
    # (N, C, H, W, size_min, size_step, count)
    (1, 3, 13, 17, 3, 2, 6),
    (2, 3, 13, 17, 1, 4, 3),  # sizes 1 (identity), 5, 9
    (2, 1, 13, 17, 3, 2, 6),
    (1, 3, 7, 9, 13, 2, 1),  # the window is larger than the whole image
    (1, 3, 7, 9, 9, 2, 3),  # 9, 11, 13 on 7 x 9
    (1, 2, 40, 37, 3, 2, 6),  # several row strips per size in the fast kernel
]


@pytest.mark.parametrize("n,c,h,w,smin,step,count", WSF_CASES)
def test_wsf_random(n, c, h, w, smin, step, count):
    rng = np.random.default_rng(h * w + smin)
    image = rng.standard_normal((n, c, h, w), dtype=np.float32)
    weights = np.exp(2.0 * rng.standard_normal((n, count, h, w))).astype(np.float32)
    attrs = {"size_min": smin, "size_step": step, "count": count}
    outs = all_forms("WeightSharingFilter", [image, weights], attrs)
    assert_forms_agree(outs, wsf_numpy(image, weights, attrs_to_sizes(**attrs)))


def test_wsf_size_one_is_identity_and_constant_image_is_kept():
    rng = np.random.default_rng(2)
    image = rng.random((1, 3, 9, 11), dtype=np.float32)
    weights = np.exp(rng.standard_normal((1, 1, 9, 11))).astype(np.float32)
    outs = all_forms(
        "WeightSharingFilter", [image, weights], {"size_min": 1, "size_step": 2, "count": 1}
    )
    for form, out in outs.items():
        assert rel_err(out, image) <= 1e-6, form
    const = np.full((1, 2, 9, 11), 3.5, np.float32)  # a weighted mean of a constant
    weights = np.exp(rng.standard_normal((1, 6, 9, 11))).astype(np.float32)
    outs = all_forms("WeightSharingFilter", [const, weights], FAN21)
    for form, out in outs.items():
        assert np.abs(out - 3.5).max() <= 3.5e-5, form


def test_wsf_zero_weight_region_gives_zero():
    rng = np.random.default_rng(3)
    image = rng.random((2, 3, 13, 17), dtype=np.float32) * 100
    weights = np.exp(rng.standard_normal((2, 6, 13, 17))).astype(np.float32)
    weights[:, :, :10, :12] = 0.0
    outs = all_forms("WeightSharingFilter", [image, weights], FAN21)
    assert_forms_agree(outs, wsf_numpy(image, weights, attrs_to_sizes(**FAN21)))
    for i, s in enumerate(attrs_to_sizes(**FAN21)):
        r = s // 2
        inside = (slice(None), slice(3 * i, 3 * i + 3), slice(0, 10 - r), slice(0, 12 - r))
        for form, out in outs.items():
            assert np.all(out[inside] == 0.0), (form, s)  # every tap weight is 0
            assert np.all(out[:, 3 * i : 3 * i + 3, 12:] > 0), (form, s)  # weights > 0 there


def test_wsf_huge_values_and_weights_spanning_exp_minus_20_to_20():
    rng = np.random.default_rng(4)
    image = (rng.random((1, 3, 13, 17)) * 1e4).astype(np.float32)
    weights = np.exp(rng.uniform(-20, 20, (1, 6, 13, 17))).astype(np.float32)
    outs = all_forms("WeightSharingFilter", [image, weights], FAN21)
    assert_forms_agree(outs, wsf_numpy(image, weights, attrs_to_sizes(**FAN21)))


def test_wsf_tiny_weights_next_to_huge_ones_stay_exact():
    """Columns < 20 weigh exp(20), the rest exp(-20): where a window holds only tiny weights
    the output is the plain window mean. A running sum (or summed-area table) that once held
    the huge values cannot resolve the tiny ones; the fast kernel's box sums only ever add
    in-window terms."""
    rng = np.random.default_rng(5)
    h, w = 12, 48
    image = (rng.random((1, 3, h, w)) * 1e4).astype(np.float32)
    weights = np.full((1, 6, h, w), np.exp(-20.0), np.float32)
    weights[..., :20] = np.exp(20.0)
    weights[..., 30:] *= rng.random((1, 6, h, w - 30), dtype=np.float32) + 0.5
    outs = all_forms("WeightSharingFilter", [image, weights], FAN21)
    expected = wsf_numpy(image, weights, attrs_to_sizes(**FAN21))
    assert_forms_agree(outs, expected)
    far = expected[..., 20 + 7 :]  # windows (<= 13 wide) entirely in the tiny-weight region
    for form, out in outs.items():
        err = np.abs(out[..., 20 + 7 :] - far) / far
        assert err.max() <= 1e-5, (form, err.max())  # per pixel, not only vs the 1e4 maximum


def test_wsf_numba_matches_on_a_tall_image():
    """Many strips and blocks per size in the fast kernel (no ORT; numpy reference)."""
    rng = np.random.default_rng(6)
    image = rng.random((1, 2, 211, 29), dtype=np.float32)
    weights = np.exp(rng.standard_normal((1, 2, 211, 29))).astype(np.float32)
    out = KERNELS["WeightSharingFilter"](image, weights, 3, 10, 2)  # sizes 3, 13
    assert rel_err(out, wsf_numpy(image, weights, [3, 13])) <= RTOL


def test_wsf_sizes_and_validation():
    assert sizes_to_attrs([3, 5, 7, 9, 11, 13]) == FAN21
    assert sizes_to_attrs([7]) == {"size_min": 7, "size_step": 2, "count": 1}
    assert attrs_to_sizes(1, 4, 3) == [1, 5, 9]
    for bad in ([4], [3, 5, 9], [3, 4], [], [-1]):
        with pytest.raises(ValueError):
            sizes_to_attrs(bad)
    image, weights = torch.rand(1, 3, 8, 8), torch.rand(1, 2, 8, 8)
    with pytest.raises(ValueError, match="importance map"):
        weight_sharing_filter(image, weights, sizes=(3, 5, 7))
    with pytest.raises(ValueError, match="odd"):
        KERNELS["WeightSharingFilter"](image.numpy(), weights.numpy(), 4, 2, 2)
    with pytest.raises(ValueError, match="importance map"):  # one message for every form
        KERNELS["WeightSharingFilter"](image.numpy(), weights.numpy(), 3, 2, 3)


# --------------------------------------------------------------------------- KernelFusion


def kernel_fusion_numpy(images: np.ndarray, logits: np.ndarray) -> np.ndarray:
    """float64: p = exp(l - max) / sum, out[:, c] = sum_i p_i images[:, i*C + c]."""
    n, sc, h, w = images.shape
    s = logits.shape[1]
    l64 = logits.astype(np.float64)
    e = np.exp(l64 - l64.max(axis=1, keepdims=True))
    p = e / e.sum(axis=1, keepdims=True)
    return (p[:, :, None] * images.reshape(n, s, sc // s, h, w)).sum(axis=1)


KF_CASES = [
    (1, 3, 6, 13, 17),
    (2, 3, 6, 13, 17),
    (2, 1, 6, 7, 9),
    (1, 3, 2, 5, 33),
    (1, 2, 1, 4, 4),
]


@pytest.mark.parametrize("n,c,s,h,w", KF_CASES)
def test_kernel_fusion_random(n, c, s, h, w):
    rng = np.random.default_rng(n * 100 + c * 10 + s)
    images = rng.standard_normal((n, s * c, h, w), dtype=np.float32)
    logits = (3.0 * rng.standard_normal((n, s, h, w))).astype(np.float32)
    outs = all_forms("KernelFusion", [images, logits], {})
    assert_forms_agree(outs, kernel_fusion_numpy(images, logits))


def test_kernel_fusion_extreme_logits_and_huge_images():
    rng = np.random.default_rng(8)
    images = (rng.standard_normal((2, 18, 13, 17)) * 1e4).astype(np.float32)
    logits = (rng.standard_normal((2, 6, 13, 17)) * 1e3).astype(np.float32)  # exp overflows
    outs = all_forms("KernelFusion", [images, logits], {})
    assert_forms_agree(outs, kernel_fusion_numpy(images, logits))
    # one logit far above the others selects its block; equal logits average the blocks
    logits = np.zeros((2, 6, 13, 17), np.float32)
    logits[:, 4] = 200.0
    for form, out in all_forms("KernelFusion", [images, logits], {}).items():
        assert rel_err(out, images[:, 12:15]) <= 1e-6, form
    equal = np.full((2, 6, 13, 17), -50.0, np.float32)
    mean = images.reshape(2, 6, 3, 13, 17).astype(np.float64).mean(axis=1)
    for form, out in all_forms("KernelFusion", [images, equal], {}).items():
        assert rel_err(out, mean) <= RTOL, form


def test_kernel_fusion_validation():
    with pytest.raises(ValueError, match="S\\*C"):
        kernel_fusion(torch.rand(1, 7, 4, 4), torch.rand(1, 3, 4, 4))
    with pytest.raises(ValueError, match="S\\*C"):
        KERNELS["KernelFusion"](
            np.zeros((1, 7, 4, 4), np.float32), np.zeros((1, 3, 4, 4), np.float32)
        )


# ------------------------------------------------------------------ gradients (torch form)


@pytest.fixture
def one_torch_thread():
    """Tiny float64 ops: with 2 OpenMP threads on a busy 2-core machine each call waits
    milliseconds for the pool (gradcheck: ~50 s instead of < 1 s)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_torch_forms_are_differentiable(one_torch_thread):
    rng = np.random.default_rng(9)

    def t(*shape, positive=False):
        x = rng.standard_normal(shape)
        return torch.from_numpy(np.exp(x) if positive else x).requires_grad_(True)

    image, weights = t(1, 2, 5, 6), t(1, 2, 5, 6, positive=True)
    assert torch.autograd.gradcheck(
        lambda a, b: weight_sharing_filter(a, b, sizes=(1, 3)), (image, weights)
    )
    image, weights = t(2, 1, 4, 5), t(2, 3, 4, 5, positive=True)
    assert torch.autograd.gradcheck(
        lambda a, b: weight_sharing_filter(a, b, sizes=(3, 5, 7)), (image, weights)
    )
    images, logits = t(2, 6, 4, 5), t(2, 3, 4, 5)
    assert torch.autograd.gradcheck(kernel_fusion, (images, logits))


def test_zero_weights_give_zero_gradient_not_nan(one_torch_thread):
    image = torch.rand(1, 3, 6, 6, requires_grad=True)
    weights = torch.zeros(1, 1, 6, 6)
    weights[..., 5, 5] = 1.0
    weights.requires_grad_(True)
    out = weight_sharing_filter(image, weights, sizes=(3,))
    out.sum().backward()
    assert torch.isfinite(image.grad).all() and torch.isfinite(weights.grad).all()
    assert float(out.detach()[0, :, 0, 0].abs().max()) == 0.0
    assert torch.allclose(out[0, :, 5, 5], image[0, :, 5, 5])


# -------------------------------------------------------------------------------- export


class TinyWSKP(nn.Module):
    """Fan21 in miniature: importance maps and fusion logits from a conv, filter, fuse."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.net = nn.Conv2d(3, 6, 3, padding=1)

    def forward(self, color: torch.Tensor) -> torch.Tensor:
        x = self.net(color)
        weights = torch.exp(x[:, :3])
        filtered = weight_sharing_filter(color, weights, sizes=(3, 5, 7))
        return kernel_fusion(filtered, x[:, 3:])


@pytest.fixture(scope="module")
def exported() -> tuple[nn.Module, onnx.ModelProto]:
    module = TinyWSKP().eval()
    h, w = torch.export.Dim("H", min=2, max=1024), torch.export.Dim("W", min=2, max=1024)
    model = to_onnx(
        module,
        (torch.rand(1, 3, 16, 24),),
        dynamic_shapes={"color": {2: h, 3: w}},
        input_names=["color"],
        output_names=["output"],
    )
    return module, model


def test_export_one_node_per_call_with_functions(exported):
    _, model = exported
    onnx.checker.check_model(model, full_check=True)
    custom = [n for n in model.graph.node if n.domain == "rtdenoise"]
    assert [n.op_type for n in custom] == ["WeightSharingFilter", "KernelFusion"]
    assert {a.name: a.i for a in custom[0].attribute} == {"size_min": 3, "size_step": 2, "count": 3}
    assert not custom[1].attribute
    assert sorted(f.name for f in model.functions) == ["KernelFusion", "WeightSharingFilter"]
    for f in model.functions:
        assert all(n.domain in ("", "ai.onnx") for n in f.node)  # standard ops only
    assert {i.domain: i.version for i in model.opset_import} == {"": 18, "rtdenoise": 1}
    dims = [d.dim_param or d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
    assert dims[:2] == [1, 3] and all(isinstance(d, str) for d in dims[2:])  # dynamic H, W


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "portable"])
def test_export_ort_matches_torch_at_two_sizes(exported, fast):
    module, model = exported
    so = ort.SessionOptions()
    if fast:
        fast_bridge.register_fast_kernels(so)
    sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(10)
    for h, w in [(19, 26), (32, 45)]:
        color = (rng.random((1, 3, h, w)) * 10).astype(np.float32)
        before = {op: fast_bridge.CALLS[op] for op in ("WeightSharingFilter", "KernelFusion")}
        (out,) = sess.run(None, {"color": color})
        for op, n0 in before.items():
            assert fast_bridge.CALLS[op] - n0 == (1 if fast else 0), op
        with torch.no_grad():
            ref = module(torch.from_numpy(color)).numpy()
        assert out.shape == (1, 3, h, w)
        assert rel_err(out, ref) <= 1e-5


# -------------------------------------------------------------------- benchmark plumbing


@pytest.mark.parametrize("op", ["WeightSharingFilter", "KernelFusion"])
def test_bench_op_runs_on_valid_example_inputs(op):
    spec = get_spec(op)
    attrs = dict(spec.default_attrs)
    inputs = spec.example_inputs((1, 3, 8, 10), attrs, np.random.default_rng(0))
    if op == "WeightSharingFilter":
        assert inputs[1].shape == (1, 6, 8, 10) and inputs[1].min() > 0  # importance maps
    model = eops.single_op_model(op, [x.shape for x in inputs], attrs)
    out_dims = [d.dim_value for d in model.graph.output[0].type.tensor_type.shape.dim]
    assert out_dims == ([1, 18, 8, 10] if op == "WeightSharingFilter" else [1, 3, 8, 10])
    result = bench_op(op, (1, 3, 8, 10), repeats=1)
    assert set(result["ms"]) == {"numba", "ort_fast", "ort_portable", "torch"}
    assert max(result["max_abs_diff"].values()) <= 1e-5
