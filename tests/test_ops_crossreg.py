"""CrossRegression and CrossBilateralFilter (Choi24) in their three forms: torch reference ==
ONNX function body (ORT, portable) == fast kernel (ORT with the numba kernels, and called
directly) == an independent brute-force numpy spelling, on every output; the filter's
registered backward == autograd through the reference == finite differences.
"""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
import torch
from op_forms import RTOL, rel_err, session

from rtdenoise.models.ops.cross_bilateral_filter import (
    band_gradient,
    cross_bilateral_filter,
    cross_bilateral_filter_reference,
)
from rtdenoise.models.ops.cross_regression import cross_regression_reference
from rtdenoise.ops import get_spec
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.kernels import KERNELS


def mirror(k: int, n: int) -> int:
    period = 2 * (n - 1)
    a = abs(k) % period
    return period - a if a >= n else a


def every_form(op: str, inputs: list[np.ndarray], attrs: dict) -> dict[str, list[np.ndarray]]:
    """{form: all outputs} for torch, ORT portable, ORT fast (both bridges) and the bare numba
    kernel."""
    spec = get_spec(op)
    with torch.no_grad():
        ref = cross_regression_reference if op == "CrossRegression" else None
        ref = ref or cross_bilateral_filter_reference
        outs = {"torch": [t.numpy() for t in ref(*map(torch.from_numpy, inputs), **attrs)]}
    feed = dict(zip(spec.input_names, inputs, strict=True))
    for name, bridge in (("portable", ""), ("ort_fast", "native"), ("ort_ext", "extensions")):
        before = fast_bridge.CALLS[op]
        outs[name] = session(op, tuple(sorted(attrs.items())), bridge).run(None, feed)
        assert fast_bridge.CALLS[op] - before == (1 if bridge else 0), name
    outs["numba"] = list(KERNELS[op](*inputs, **attrs))
    return outs


def assert_all_agree(outs: dict[str, list[np.ndarray]], expected: list[np.ndarray]) -> None:
    for form, arrays in outs.items():
        assert len(arrays) == len(expected), form
        for k, (out, ref) in enumerate(zip(arrays, expected, strict=True)):
            assert out.shape == ref.shape and out.dtype == np.float32, (form, k)
            assert np.isfinite(out).all(), (form, k)
            assert rel_err(out, ref) <= RTOL, (form, k, rel_err(out, ref))


# ---------------------------------------------------------------------------- CrossRegression


def cross_regression_numpy(ya, yb, albedo, normal, window, stride):
    """Brute force in float64: one centre, one window pixel, one output pixel at a time."""

    def pilot(y, t, rho, nrm):
        _, h, w = y.shape
        r = window // 2
        var = np.zeros((h, w))
        for py in range(h):
            for px in range(w):
                near = [
                    y[:, qy, qx]
                    for qy in range(max(0, py - 1), min(h, py + 2))
                    for qx in range(max(0, px - 1), min(w, px + 2))
                    if (qy, qx) != (py, px)
                ]
                var[py, px] = ((y[:, py, px] - np.mean(near, axis=0)) ** 2).sum()
        sigma = np.sqrt(var)

        def xw(qy, qx, cy, cx):
            dy = y[:, qy, qx] - y[:, cy, cx]
            wgt = np.exp(-(dy**2).sum() / (var[cy, cx] + var[qy, qx] + 1e-4)) + 1e-7
            x = np.ones((3, 6))
            x[:, 1] = dy / (sigma[cy, cx] + sigma[qy, qx] + 1e-2)
            x[:, 2] = rho[:, qy, qx] - rho[:, cy, cx]
            x[:, 3:] = nrm[:, qy, qx] - nrm[:, cy, cx]
            return x, wgt

        beta = {}
        for cy in range(0, h, stride):
            for cx in range(0, w, stride):
                a, b = np.zeros((3, 6, 6)), np.zeros((3, 6))
                for qy in (mirror(cy + d, h) for d in range(-r, r + 1)):
                    for qx in (mirror(cx + d, w) for d in range(-r, r + 1)):
                        x, wgt = xw(qy, qx, cy, cx)
                        for k in range(3):
                            a[k] += wgt * np.outer(x[k], x[k])
                            b[k] += wgt * x[k] * t[k, qy, qx]
                beta[cy, cx] = [np.linalg.solve(a[k] + 1e-3 * np.eye(6), b[k]) for k in range(3)]
        out = np.zeros((3, h, w))
        for py in range(h):
            for px in range(w):
                num, den = np.zeros(3), 0.0
                for (cy, cx), coef in beta.items():
                    if abs(py - cy) <= r and abs(px - cx) <= r:
                        x, wgt = xw(py, px, cy, cx)
                        num += wgt * np.array([x[k] @ coef[k] for k in range(3)])
                        den += wgt
                out[:, py, px] = np.maximum(num / den, 0.0)
        return out

    f64 = [a.astype(np.float64) for a in (ya, yb, albedo, normal)]
    ya, yb, albedo, normal = f64
    n = ya.shape[0]
    pa = np.stack([pilot(ya[i], yb[i], albedo[i], normal[i]) for i in range(n)])
    pb = np.stack([pilot(yb[i], ya[i], albedo[i], normal[i]) for i in range(n)])
    return [pa, pb]


CR_CASES = [
    # (shape, window, stride)
    ((1, 3, 13, 17), 17, 4),
    ((2, 3, 9, 12), 7, 2),
    ((1, 3, 5, 4), 17, 4),  # windows reach 8 px past a 4-px-wide image: repeated mirroring
    ((1, 3, 16, 16), 9, 5),  # the largest stride that still covers every pixel
]


@pytest.mark.parametrize("shape,window,stride", CR_CASES)
def test_cross_regression_matches_brute_force(shape, window, stride):
    attrs = {"window": window, "stride": stride}
    inputs = get_spec("CrossRegression").example_inputs(shape, attrs, np.random.default_rng(7))
    outs = every_form("CrossRegression", inputs, attrs)
    assert_all_agree(outs, cross_regression_numpy(*inputs, window, stride))


def test_cross_regression_crosses_the_buffers_and_denoises():
    """Swapping A and B swaps the pilots; the pilots are far closer to the noise-free value than
    the noisy buffers; a constant image stays constant."""
    attrs = {"window": 17, "stride": 4}
    rng = np.random.default_rng(3)
    h, w = 24, 28
    yy, xx = np.mgrid[0:h, 0:w]
    clean = (0.5 + 0.4 * np.sin(xx / 4.0 + np.arange(3)[:, None, None]) + 1.0 * (xx > 13))[None]
    albedo = np.broadcast_to(0.3 + 0.5 * (xx > 13), (1, 3, h, w)).astype(np.float32)
    normal = np.zeros((1, 3, h, w), np.float32)
    normal[:, 2] = 1.0

    def noisy(samples: int) -> np.ndarray:  # log1p of 1-spp radiance, clean x Exp(1)
        return np.log1p(clean[None] * rng.exponential(1.0, (samples, 1, 3, h, w)))

    expected = noisy(512).mean(axis=0)  # E[log1p(radiance)] per pixel: what a pilot estimates
    ya, yb = (noisy(1)[0].astype(np.float32) for _ in range(2))
    pa, pb = KERNELS["CrossRegression"](ya, yb, albedo, normal, **attrs)
    qa, qb = KERNELS["CrossRegression"](yb, ya, albedo, normal, **attrs)
    np.testing.assert_array_equal(pa, qb)
    np.testing.assert_array_equal(pb, qa)
    for buffer, pilot in ((ya, pa), (yb, pb)):
        mse_in = ((buffer - expected) ** 2).mean()
        assert ((pilot - expected) ** 2).mean() < 0.25 * mse_in
    const = np.full((1, 3, 12, 12), 0.7, np.float32)
    outs = every_form(
        "CrossRegression", [const, const, const * 0 + 0.5, normal[..., :12, :12]], attrs
    )
    for form, (ca, cb) in outs.items():
        # beta_0 = sum w y / (sum w + 1e-3): 0.7 shrunk by about 1e-3 / 289
        assert np.abs(ca - 0.7).max() < 1e-5 and np.abs(cb - 0.7).max() < 1e-5, form


def test_cross_regression_fireflies_and_flat_guides_stay_finite():
    """A 1e4 firefly (log1p ~ 9.2), zero normals (background) and constant albedo: the ridge
    keeps every system solvable and all forms agree."""
    attrs = {"window": 17, "stride": 4}
    spec = get_spec("CrossRegression")
    ya, yb, albedo, normal = spec.example_inputs((1, 3, 20, 20), attrs, np.random.default_rng(4))
    ya[:, :, 5, 7] = np.log1p(1e4)
    yb[:, :, 12, 3] = np.log1p(1e4)
    normal[:, :, :, 10:] = 0.0
    albedo[:] = 0.5
    outs = every_form("CrossRegression", [ya, yb, albedo, normal], attrs)
    assert_all_agree(outs, cross_regression_numpy(ya, yb, albedo, normal, 17, 4))


# ----------------------------------------------------------------------- CrossBilateralFilter


def cross_bilateral_numpy(pa, pb, albedo, normal, band, window):
    """Brute force in float64: every tap of every pixel."""
    n, _, h, w = pa.shape
    r = window // 2
    f64 = [a.astype(np.float64) for a in (pa, pb, albedo, normal, band)]
    pa, pb, albedo, normal, band = f64
    outs = [np.zeros((n, 4, h, w)), np.zeros((n, 4, h, w))]
    douts = [np.zeros((n, 16, h, w)), np.zeros((n, 16, h, w))]
    for b in range(n):
        for y in range(h):
            for x in range(w):
                bd = band[b, :, y, x]
                for dy in range(-r, r + 1):
                    for dx in range(-r, r + 1):
                        qy, qx = mirror(y + dy, h), mirror(x + dx, w)

                        def dist(img, at=(b, qy, qx), ctr=(b, y, x)):
                            return (
                                (img[at[0], :, at[1], at[2]] - img[ctr[0], :, ctr[1], ctr[2]]) ** 2
                            ).sum()

                        d_rho, d_n, d_p = dist(albedo), dist(normal), (dy * dy + dx * dx) / r**2
                        for k, (img, bf) in enumerate(((pa, bd[0]), (pb, bd[1]))):
                            dists = (dist(img), d_rho, d_n, d_p)
                            m = np.exp(-bf * dists[0] - bd[2] * d_rho - bd[3] * d_n - bd[4] * d_p)
                            f = img[b, :, qy, qx]
                            outs[k][b, :3, y, x] += m * f
                            outs[k][b, 3, y, x] += m
                            for j, dk in enumerate(dists):
                                douts[k][b, 4 * j : 4 * j + 3, y, x] += m * dk * f
                                douts[k][b, 4 * j + 3, y, x] += m * dk
    return [*outs, *douts]


@pytest.mark.parametrize(
    "shape,window", [((1, 3, 9, 13), 11), ((2, 3, 7, 6), 5), ((1, 3, 3, 2), 7)]
)
def test_cross_bilateral_filter_matches_brute_force(shape, window):
    attrs = {"window": window}
    spec = get_spec("CrossBilateralFilter")
    inputs = spec.example_inputs(shape, attrs, np.random.default_rng(window))
    outs = every_form("CrossBilateralFilter", inputs, attrs)
    assert_all_agree(outs, cross_bilateral_numpy(*inputs, window))


def test_cross_bilateral_filter_huge_bandwidths_keep_only_the_centre():
    """At initialisation the network outputs x ~ 0, band = 1 / (x^2 + 1e-4) ~ 1e4: every tap
    but the centre vanishes, sum = the pilot, weight sum = 1, dsums = 0."""
    spec = get_spec("CrossBilateralFilter")
    pa, pb, albedo, normal, _ = spec.example_inputs(
        (1, 3, 8, 9), {"window": 11}, np.random.default_rng(1)
    )
    band = np.full((1, 5, 8, 9), 1e4, np.float32)
    outs = every_form("CrossBilateralFilter", [pa, pb, albedo, normal, band], {"window": 11})
    for form, (sa, sb, da, db) in outs.items():
        np.testing.assert_allclose(sa[:, :3], pa, rtol=1e-6, err_msg=form)
        np.testing.assert_allclose(sb[:, 3], 1.0, rtol=1e-6, err_msg=form)
        assert np.abs(da).max() < 1e-6 and np.abs(db).max() < 1e-6, form


def test_cross_bilateral_band_gradient_three_ways():
    """d L / d band through the op's registered backward (dsum outputs + standard ops) ==
    autograd through the tensor-op reference == central finite differences (float64)."""
    spec = get_spec("CrossBilateralFilter")
    inputs = spec.example_inputs((1, 3, 6, 7), {"window": 5}, np.random.default_rng(2))
    guides = [torch.from_numpy(x).double() for x in inputs[:4]]
    band0 = torch.from_numpy(inputs[4]).double() * 0.2
    g = torch.Generator().manual_seed(0)
    weights = [torch.randn(1, 4, 6, 7, generator=g, dtype=torch.float64) for _ in range(2)]

    def loss(fn, band):
        sa, sb, _, _ = fn(*guides, band, window=5)
        # a nonlinear loss, like the model's (ratios of the sums)
        return ((sa[:, :3] / (sa[:, 3:] + 1e-4)) * weights[0][:, :3]).sum() + (
            sb * weights[1]
        ).sum()

    grads = []
    for fn in (cross_bilateral_filter, cross_bilateral_filter_reference):
        band = band0.clone().requires_grad_()
        loss(fn, band).backward()
        grads.append(band.grad)
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-10, atol=1e-12)
    assert grads[0].abs().max() > 1e-3  # the bandwidths matter
    eps = 1e-6
    for k, (y, x) in [(0, (1, 2)), (1, (4, 6)), (2, (0, 0)), (3, (5, 3)), (4, (2, 5))]:
        plus, minus = band0.clone(), band0.clone()
        plus[0, k, y, x] += eps
        minus[0, k, y, x] -= eps
        with torch.no_grad():
            numeric = (
                loss(cross_bilateral_filter_reference, plus)
                - loss(cross_bilateral_filter_reference, minus)
            ) / (2 * eps)
        assert abs(float(numeric) - float(grads[0][0, k, y, x])) < 1e-6 * max(
            1, abs(float(numeric))
        )


def test_band_gradient_adds_the_shared_bandwidths():
    """band_A only sees buffer A's colour term, band_B only B's; albedo, normal and position
    bandwidths collect both buffers."""
    da = torch.zeros(1, 16, 1, 1)
    db = torch.zeros(1, 16, 1, 1)
    da[0, 3::4, 0, 0] = torch.tensor([1.0, 2.0, 3.0, 4.0])  # sum m D_k for k = colour, rho, n, p
    db[0, 3::4, 0, 0] = torch.tensor([10.0, 20.0, 30.0, 40.0])
    ga = torch.tensor([0.0, 0.0, 0.0, 1.0]).view(1, 4, 1, 1)  # d L / d (sum m) = 1
    grad = band_gradient(ga, ga, da, db)
    assert grad.flatten().tolist() == [-1.0, -10.0, -22.0, -33.0, -44.0]


def test_models_refuse_bad_calls():
    with pytest.raises(ValueError, match="band has 4 channels"):
        cross_bilateral_filter(*(torch.rand(1, 3, 8, 8) for _ in range(4)), torch.rand(1, 4, 8, 8))
    with pytest.raises(ValueError, match="stride"):
        KERNELS["CrossRegression"](*(np.random.rand(1, 3, 8, 8) for _ in range(4)), 5, 4)
    with pytest.raises(ValueError, match="too small"):
        KERNELS["CrossBilateralFilter"](
            *(np.random.rand(1, 3, 1, 8) for _ in range(4)), np.random.rand(1, 5, 1, 8), 5
        )


def test_portable_session_runs_without_the_fast_kernels():
    """The function bodies alone (stock ORT) run both ops (no fast kernel registered)."""
    spec = get_spec("CrossRegression")
    inputs = spec.example_inputs(
        (1, 3, 8, 8), {"window": 17, "stride": 4}, np.random.default_rng(0)
    )
    sess = session("CrossRegression", (("stride", 4), ("window", 17)), "")
    assert isinstance(sess, ort.InferenceSession)
    out = sess.run(None, dict(zip(spec.input_names, inputs, strict=True)))
    assert all(np.isfinite(o).all() for o in out)
