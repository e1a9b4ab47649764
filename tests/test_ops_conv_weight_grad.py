"""ConvWeightGrad (the weight gradients of crossreg's backward pass) in every form equals an
independent float64 numpy spelling and autograd's gradient of the convolution, on the U-Net's
channel counts, odd sizes and every blocking remainder of the C++ kernel; and the traced
backward uses it for the 3 x 3 convolutions."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from op_forms import all_forms, assert_forms_agree


def weight_grad_numpy(x: np.ndarray, g: np.ndarray, k: int, p: int) -> np.ndarray:
    """sum over n, y, x of g[n, o, y, x] x_pad[n, i, y + ky, x + kx], tap by tap (float64)."""
    n, ci, h, w = x.shape
    ho, wo = g.shape[2:]
    xp = np.pad(x.astype(np.float64), ((0, 0), (0, 0), (p, p), (p, p)))
    out = np.zeros((g.shape[1], ci, k, k))
    for ky in range(k):
        for kx in range(k):
            out[:, :, ky, kx] = np.einsum("noyx,niyx->oi", g, xp[:, :, ky : ky + ho, kx : kx + wo])
    return out


CASES = [
    # (N, C_in, C_out, H, W, K, padding)
    (1, 15, 8, 20, 36, 3, 1),  # crossreg's first conv: 15 inputs
    (1, 16, 32, 9, 13, 3, 1),  # odd sizes, a pixel tail under the 8 lanes
    (1, 5, 7, 3, 2100, 3, 1),  # output-channel remainder, a row longer than one chunk
    (2, 3, 4, 10, 11, 5, 2),  # a batch; 5 kernel columns: a 3 + 2 column tile
    (1, 4, 6, 9, 9, 3, 0),  # 'valid' convolution: a smaller gradient
]


@pytest.mark.parametrize("n,ci,co,h,w,k,p", CASES)
def test_every_form_is_the_weight_gradient(n, ci, co, h, w, k, p):
    rng = np.random.default_rng(ci * co + h)
    x = np.maximum(rng.standard_normal((n, ci, h, w)), -0.2).astype(np.float32)
    g = rng.standard_normal((n, co, h + 2 * p - k + 1, w + 2 * p - k + 1)).astype(np.float32)
    expected = weight_grad_numpy(x, g, k, p)
    xt = torch.from_numpy(x)
    weight = torch.zeros(co, ci, k, k, requires_grad=True)
    out = F.conv2d(xt, weight, padding=p)
    (autograd,) = torch.autograd.grad(out, weight, torch.from_numpy(g))
    np.testing.assert_allclose(autograd.numpy(), expected, rtol=1e-4, atol=1e-4)
    outs = all_forms("ConvWeightGrad", [x, g], {"kernel_size": k, "padding": p})
    assert_forms_agree(outs, expected.astype(np.float32))


def test_the_traced_backward_spells_3x3_weight_gradients_as_the_op():
    """models/online.py's convolution_backward: a 3 x 3 conv's weight gradient is one
    ConvWeightGrad call (while exporting: the custom op), equal to autograd's."""
    from rtdenoise.models.online import _convolution_backward
    from rtdenoise.models.ops import export_mode, observe_calls

    rng = np.random.default_rng(5)
    x = torch.from_numpy(rng.standard_normal((1, 8, 12, 14)).astype(np.float32))
    weight = torch.from_numpy(rng.standard_normal((16, 8, 3, 3)).astype(np.float32))
    g = torch.from_numpy(rng.standard_normal((1, 16, 12, 14)).astype(np.float32))
    args = (g, x, weight, [16], [1, 1], [1, 1], [1, 1], False, [0, 0], 1, [True, True, True])
    w_param = weight.clone().requires_grad_(True)
    x_param = x.clone().requires_grad_(True)
    grads = torch.autograd.grad(F.conv2d(x_param, w_param, padding=1), (x_param, w_param), g)
    for mode in (False, True):
        calls: list[str] = []
        context = export_mode.exporting() if mode else torch.no_grad()
        with context, observe_calls(lambda op, *_, seen=calls: seen.append(op.name)):
            grad_in, grad_w, grad_b = _convolution_backward(*args)
        assert calls == ["ConvWeightGrad"]
        torch.testing.assert_close(grad_in, grads[0], rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(grad_w, grads[1], rtol=1e-4, atol=1e-4)
        torch.testing.assert_close(grad_b, g.sum(dim=(0, 2, 3)))


def test_the_cpp_kernel_gives_the_same_bits_on_any_thread_count():
    """The C++ kernel sums fixed 8-row blocks and adds them in block order: 1, 2 or 3 threads
    give the same bits (a sum split by thread would not)."""
    import onnxruntime as ort

    from rtdenoise.export import ops as eops
    from rtdenoise.runtime import bridge as fast_bridge
    from rtdenoise.runtime.bridge import native_cpp

    if native_cpp.unavailable_reason() is not None:
        pytest.skip("the C++ library was not built")
    attrs = {"kernel_size": 3, "padding": 1}
    model = eops.single_op_model("ConvWeightGrad", None, attrs, with_function=False)
    so = ort.SessionOptions()
    assert fast_bridge.register_fast_kernels(so, "native-cpp", ["ConvWeightGrad"]) == "native-cpp"
    sess = ort.InferenceSession(model.SerializeToString(), so, ["CPUExecutionProvider"])
    rng = np.random.default_rng(1)
    feed = {
        "input": rng.standard_normal((1, 8, 61, 77)).astype(np.float32),
        "grad_output": rng.standard_normal((1, 16, 61, 77)).astype(np.float32),
    }
    outs = []
    for team in (1, 2, 3):
        with fast_bridge.kernel_threads("native-cpp", team):
            outs.append(sess.run(None, feed)[0])
    for out in outs[1:]:
        np.testing.assert_array_equal(out, outs[0])
