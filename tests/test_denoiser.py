"""The runtime executor `Denoiser` on small contract models with numpy references."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from contract_models import (
    EmaReference,
    HalfresReference,
    blowup_model,
    ema_model,
    halfres_model,
    probe_model,
    samples_model,
)

from rtdenoise.runtime import ContractError, Denoiser, InputError, resolve_model

TOL = {"rtol": 1e-5, "atol": 1e-6}


@pytest.fixture(scope="module")
def ema() -> bytes:
    return ema_model()


@pytest.fixture(scope="module")
def probe() -> bytes:
    return probe_model()


def frames(n: int, h: int, w: int, seed: int = 0, channels: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.random((channels, h, w), dtype=np.float32) * 4 for _ in range(n)]


def albedo_frames(n: int, h: int, w: int, seed: int = 1) -> list[np.ndarray]:
    """Albedo in [0, 1), the contract's range (the input guard clamps to it)."""
    return [f / 4 for f in frames(n, h, w, seed)]


@pytest.mark.parametrize("io_binding", [True, False])
def test_ema_matches_numpy_over_8_frames(ema: bytes, io_binding: bool) -> None:
    den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    ref = EmaReference()
    for i, (color, albedo) in enumerate(
        zip(frames(8, 64, 64), albedo_frames(8, 64, 64, 1), strict=True)
    ):
        out = den.process({"color": color, "albedo": albedo})
        assert out.shape == (3, 64, 64) and out.dtype == np.float32
        np.testing.assert_allclose(out, ref.step(color, albedo, i == 0), **TOL)
        assert den.frame_index == i + 1
    assert den.frames_processed == 8 and den.total_nonfinite == 0


def test_properties(ema: bytes) -> None:
    den = Denoiser(ema, fast_kernels=False)
    assert den.family == "ema" and den.config == {"k": 0.5}
    assert den.required_buffers == ("color", "albedo")
    assert [(s.name, s.channels, s.scale) for s in den.state_specs] == [("acc", 3, 1)]
    assert den.pad_multiple == 4 and den.frame_index == 0
    assert den.note == "linear radiance" and den.providers == ["CPUExecutionProvider"]


@pytest.mark.parametrize("io_binding", [True, False])
def test_zero_state_and_reset_flag(probe: bytes, io_binding: bool) -> None:
    """probe: output = state + color + 100 * reset, so the output shows what was fed."""
    den = Denoiser(probe, fast_kernels=False, io_binding=io_binding)
    c = frames(6, 8, 8)
    np.testing.assert_array_equal(den.process({"color": c[0]}), c[0] + 100)  # zeros, reset=1
    np.testing.assert_allclose(den.process({"color": c[1]}), c[0] + 100 + c[1], **TOL)
    den.reset()
    assert den.frame_index == 0
    np.testing.assert_array_equal(den.process({"color": c[2]}), c[2] + 100)
    np.testing.assert_allclose(den.process({"color": c[3]}), c[2] + 100 + c[3], **TOL)
    np.testing.assert_array_equal(den.process({"color": c[4]}, reset=True), c[4] + 100)
    assert den.frame_index == 1


@pytest.mark.parametrize("io_binding", [True, False])
def test_resolution_change_resets(ema: bytes, probe: bytes, io_binding: bool) -> None:
    den = Denoiser(probe_model(pad_multiple=4), fast_kernels=False, io_binding=io_binding)
    a, b = frames(2, 13, 17), frames(2, 14, 18, 1)  # both pad to 16 x 20
    den.process({"color": a[0]})
    np.testing.assert_allclose(den.process({"color": a[1]}), a[0] + a[1] + 100, **TOL)
    np.testing.assert_array_equal(den.process({"color": b[0]}), b[0] + 100)
    np.testing.assert_allclose(den.process({"color": b[1]}), b[0] + b[1] + 100, **TOL)

    den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    ref = EmaReference()
    for color, albedo in zip(frames(3, 64, 64), albedo_frames(3, 64, 64, 1), strict=True):
        den.process({"color": color, "albedo": albedo})
    for size in [(32, 48), (64, 64)]:
        ref = EmaReference()
        pairs = zip(frames(3, *size, 2), albedo_frames(3, *size, 3), strict=True)
        for i, (color, albedo) in enumerate(pairs):
            out = den.process({"color": color, "albedo": albedo})
            assert out.shape == (3, *size)
            np.testing.assert_allclose(out, ref.step(color, albedo, i == 0), **TOL)


@pytest.mark.parametrize("io_binding", [True, False])
def test_edge_margin_repeats_the_edge_on_every_side_and_crops_it(io_binding: bool) -> None:
    """`rtdenoise.edge_margin` = 3: every buffer gets 3 edge pixels on every side, then the
    bottom and right up to the pad multiple (13 x 17 -> 19 x 23 -> 20 x 24, the state's size),
    and the output is the frame's own 13 x 17 from (3, 3); the numpy reference does the same
    by np.pad. Without the margin the same model differs at the edge (the box blur and the 4 x 4
    pooling grid see other pixels), so the test tells a margin that was not applied, or
    cropped from the wrong corner."""
    model = ema_model(metadata={"rtdenoise.edge_margin": "3"})
    den = Denoiser(model, fast_kernels=False, io_binding=io_binding)
    assert den.edge_margin == 3 and "edge_margin=3" in repr(den)
    assert den.contract.declaration.edge_margin == 3
    ref, plain = EmaReference(margin=3), EmaReference()
    for i, (color, albedo) in enumerate(
        zip(frames(6, 13, 17), albedo_frames(6, 13, 17, 1), strict=True)
    ):
        out = den.process({"color": color, "albedo": albedo})
        assert out.shape == (3, 13, 17) and out.flags.c_contiguous
        np.testing.assert_allclose(out, ref.step(color, albedo, i == 0), **TOL)
        unpadded = plain.step(color, albedo, i == 0)
    assert den.state_value("acc").shape == (1, 3, 20, 24)
    assert not np.allclose(out, unpadded, **TOL)
    assert Denoiser(ema_model(), fast_kernels=False).edge_margin == 0  # the key is optional


@pytest.mark.parametrize("io_binding", [True, False])
def test_odd_size_padded_and_cropped(ema: bytes, io_binding: bool) -> None:
    den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    ref = EmaReference()
    for i, (color, albedo) in enumerate(
        zip(frames(8, 13, 17), albedo_frames(8, 13, 17, 1), strict=True)
    ):
        batched = color[None] if i % 2 else color  # (1, C, H, W) is accepted too
        out = den.process({"color": batched, "albedo": albedo, "normal": np.zeros(3)})
        assert out.shape == (3, 13, 17) and out.flags.c_contiguous
        np.testing.assert_allclose(out, ref.step(color, albedo, i == 0), **TOL)
    # zero padding instead of replicate padding would change the border pixels
    zero = np.pad(color, ((0, 0), (0, 3), (0, 3)))[:, :16, :20]
    assert not np.allclose(
        EmaReference().step(zero, np.pad(albedo, ((0, 0), (0, 3), (0, 3))), True)[:, :13, :17],
        EmaReference().step(color, albedo, True),
        **TOL,
    )


@pytest.mark.parametrize("io_binding", [True, False])
def test_half_resolution_state(io_binding: bool) -> None:
    den = Denoiser(halfres_model(), fast_kernels=False, io_binding=io_binding)
    ref = HalfresReference()
    colors, depths = frames(8, 31, 21), frames(8, 31, 21, 1, channels=1)
    for i, (color, depth) in enumerate(zip(colors, depths, strict=True)):
        out = den.process({"color": color, "depth": depth})
        assert out.shape == (3, 31, 21)
        np.testing.assert_allclose(out, ref.step(color, depth, i == 0), **TOL)
    state = den.state_value("low")
    assert state.shape == (1, 4, 16, 11) == den.state_specs[0].shape(32, 22)
    np.testing.assert_allclose(state[0], ref.low, **TOL)


@pytest.mark.parametrize("io_binding", [True, False])
def test_nonfinite_inputs_replaced_and_counted(ema: bytes, io_binding: bool) -> None:
    den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    ref = EmaReference()
    colors, albedos = frames(5, 16, 16), albedo_frames(5, 16, 16, 1)
    bad = colors[2].copy()
    bad[0, 0, 0], bad[1, 5, 7], bad[2, 15, 15] = np.nan, np.inf, -np.inf
    bad[0, 3, 3] = np.nan
    for i in range(5):
        color = bad if i == 2 else colors[i]
        out = den.process({"color": color, "albedo": albedos[i]})
        clean = np.nan_to_num(color, nan=0.0, posinf=0.0, neginf=0.0)
        np.testing.assert_allclose(out, ref.step(clean, albedos[i], i == 0), **TOL)
        assert np.isfinite(out).all()
        assert den.last_nonfinite == (4 if i == 2 else 0)
    assert den.total_nonfinite == 4 and den.total_state_nonfinite == 0
    assert np.isnan(bad[0, 0, 0])  # the caller's array is untouched


@pytest.mark.parametrize("io_binding", [True, False])
def test_nonfinite_state_and_output_replaced(io_binding: bool) -> None:
    """blowup: state_next = output = 1e30 * state + color overflows on frame 3 from finite
    input: the output comes back finite (0 there), counted, and the next frame starts anew."""
    den = Denoiser(blowup_model(), fast_kernels=False, io_binding=io_binding)
    one = np.ones((3, 4, 4), np.float32)
    np.testing.assert_array_equal(den.process({"color": one}), one)
    assert den.process({"color": one}).min() > 1e29
    with pytest.warns(RuntimeWarning, match="NaN/Inf state"):
        out = den.process({"color": one})  # 1e30 * 1e30 = inf
    np.testing.assert_array_equal(out, 0 * one)  # never NaN/Inf from process itself
    assert den.last_guard.output_nonfinite == 16 and den.last_state_nonfinite == 48
    np.testing.assert_array_equal(den.process({"color": 2 * one}), 2 * one)  # a new history
    assert den.last_guard.reset == "non-finite output in the previous frame"
    assert den.guard_totals.output_nonfinite == 16 and den.total_nonfinite == 0


@pytest.mark.parametrize("io_binding", [True, False])
def test_rank5_samples_stateless(io_binding: bool) -> None:
    den = Denoiser(samples_model(), fast_kernels=False, io_binding=io_binding)
    assert den.state_specs == () and not den.contract.has_reset
    rng = np.random.default_rng(3)
    for s in (4, 2):  # S may change from frame to frame
        samples = rng.random((s, 3, 13, 17), dtype=np.float32)
        out = den.process({"samples": samples if s == 4 else samples[None]})
        np.testing.assert_allclose(out, samples.mean(axis=0), **TOL)
    with pytest.raises(InputError, match=r"'samples' has shape \(4, 2, 13, 17\).*\(S, 3, H, W\)"):
        den.process({"samples": np.zeros((4, 2, 13, 17), np.float32)})


def test_io_binding_equals_session_run(ema: bytes) -> None:
    outs = {}
    for io_binding in (True, False):
        den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
        seq = []
        for i, (c, a) in enumerate(
            zip(frames(8, 24, 20, 5), albedo_frames(8, 24, 20, 6), strict=True)
        ):
            if i == 3:
                c = c.copy()
                c[0, 1, 1] = np.nan
            if i == 5:
                c, a = c[:, :13], a[:, :13]
            seq.append(den.process({"color": c, "albedo": a}, reset=i == 6))
        outs[io_binding] = seq
    for bound, plain in zip(outs[True], outs[False], strict=True):
        np.testing.assert_array_equal(bound, plain)


def test_fast_kernels_default_same_result(ema: bytes) -> None:
    color, albedo = frames(1, 16, 16)[0], albedo_frames(1, 16, 16, 1)[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # fast kernels may not be installed
        fast = Denoiser(ema, threads=1)
    portable = Denoiser(ema, fast_kernels=False)
    assert isinstance(fast.fast_kernels, bool) and portable.fast_kernels is False
    np.testing.assert_array_equal(
        fast.process({"color": color, "albedo": albedo}),
        portable.process({"color": color, "albedo": albedo}),
    )


def test_missing_buffer(ema: bytes) -> None:
    den = Denoiser(ema, fast_kernels=False)
    with pytest.raises(InputError, match=r"missing buffer 'albedo'.*color, albedo; given: color"):
        den.process({"color": np.zeros((3, 8, 8), np.float32)})


@pytest.mark.parametrize(
    ("albedo", "match"),
    [
        (np.zeros((4, 8, 8)), r"'albedo' has shape \(4, 8, 8\).*expected \(3, H, W\)"),
        (np.zeros((2, 3, 8, 8)), r"'albedo' has shape \(2, 3, 8, 8\)"),
        (np.zeros((8, 8)), r"'albedo' has shape \(8, 8\)"),
        (np.zeros((3, 8, 12)), r"'albedo' has shape \(3, 8, 12\); expected H x W = 8 x 8"),
        (np.zeros((3, 8, 8), bool), r"'albedo' .* dtype bool"),
    ],
)
def test_bad_buffer_shapes(ema: bytes, albedo: np.ndarray, match: str) -> None:
    den = Denoiser(ema, fast_kernels=False)
    with pytest.raises(InputError, match=match):
        den.process({"color": np.zeros((3, 8, 8), np.float32), "albedo": albedo})
    assert den.frames_processed == 0


def test_other_dtypes_converted(ema: bytes) -> None:
    den = Denoiser(ema, fast_kernels=False)
    color, albedo = frames(1, 8, 8)[0], albedo_frames(1, 8, 8, 1)[0]
    out = den.process({"color": color.astype(np.float64), "albedo": albedo.astype(np.float16)})
    ref = EmaReference().step(color, albedo.astype(np.float16).astype(np.float32), True)
    np.testing.assert_allclose(out, ref, **TOL)


def _meta_state(**entry) -> dict[str, str]:
    return {"rtdenoise.state": json.dumps([{"name": "acc", "channels": 3, "scale": 1} | entry])}


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"metadata": {"rtdenoise.contract": None}}, "metadata key 'rtdenoise.contract' missing"),
        ({"metadata": {"rtdenoise.pad_multiple": None}}, "'rtdenoise.pad_multiple' missing"),
        ({"metadata": {"rtdenoise.contract": "2"}}, "is '2', this runtime reads version 1"),
        ({"drop_state_next": True}, "'state.acc' has no matching output 'state_next.acc'"),
        ({"metadata": _meta_state(channels=4)}, "'state.acc' has 3 channels in the graph"),
        ({"metadata": _meta_state(scale=8)}, "pad_multiple 4 is not a multiple of state 'acc'"),
        ({"metadata": {"rtdenoise.state": "[]"}}, "graph input 'state.acc' is not listed"),
        ({"metadata": {"rtdenoise.config": "{oops"}}, "rtdenoise.config is not valid JSON"),
        ({"metadata": {"rtdenoise.pad_multiple": "x"}}, "pad_multiple is 'x', not an integer"),
        ({"metadata": {"rtdenoise.edge_margin": "8px"}}, "edge_margin is '8px', not an integer"),
        ({"metadata": {"rtdenoise.edge_margin": "-1"}}, "edge_margin must be in 0..256, got -1"),
        ({"metadata": {"rtdenoise.edge_margin": "300"}}, "edge_margin must be in 0..256, got 3"),
        ({"metadata": {"rtdenoise.inputs": '{"buffers": ["color"]}'}}, "input 'albedo' is nei"),
        (
            {"metadata": {"rtdenoise.inputs": '{"buffers": ["color", "albedo", "normal"]}'}},
            "buffer 'normal' is listed in rtdenoise.inputs but is not a graph input",
        ),
        ({"metadata": {"rtdenoise.inputs": '{"buffers": ["rgb"]}'}}, "unknown buffer 'rgb'"),
        ({"reset_shape": [1]}, "'reset' must be a rank-0 scalar"),
        (
            {"metadata": {"rtdenoise.online": '{"statistics": ["acc"]}'}},
            "statistics must list states of size \\[1, 1\\], got \\['acc'\\]",
        ),
        ({"extra_input": "normal"}, "graph input 'normal' is neither a listed buffer"),
    ],
)
def test_contract_violations(kwargs: dict, match: str) -> None:
    with pytest.raises(ContractError, match=match) as info:
        Denoiser(ema_model(**kwargs), fast_kernels=False)
    assert "not an rtdenoise contract-v1 model" in str(info.value)
    assert "\n" not in str(info.value)


def test_model_sources(ema: bytes, tmp_path) -> None:
    path = tmp_path / "ema.onnx"
    path.write_bytes(ema)
    den = Denoiser(path, fast_kernels=False)
    assert den.source == str(path) and resolve_model(str(path)) == path
    with pytest.raises(InputError, match="no such model file"):
        Denoiser(tmp_path / "missing.onnx")
    with pytest.raises(InputError, match="is a folder"):
        resolve_model(tmp_path)
    (tmp_path / "model.pt").write_bytes(b"x")
    with pytest.raises(InputError, match="PyTorch checkpoint; export it first"):
        resolve_model(tmp_path / "model.pt")
    with pytest.raises(InputError, match="demo:no-such-family"):
        resolve_model("demo:no-such-family")
    with pytest.raises(InputError, match="ONNX Runtime cannot load the model"):
        Denoiser(b"not an onnx model", fast_kernels=False)


def test_providers(ema: bytes) -> None:
    with pytest.raises(InputError, match="'CUDAExecutionProvider' is not available.*CPUExec"):
        Denoiser(ema, fast_kernels=False, providers=["cuda"])
    den = Denoiser(ema, fast_kernels=False, providers=["cpu"], threads=1)
    assert den.providers == ["CPUExecutionProvider"]
    with pytest.raises(InputError, match="threads must be >= 1"):
        Denoiser(ema, fast_kernels=False, threads=0)


@pytest.mark.parametrize("io_binding", [True, False])
def test_interleaved_half_float_with_alpha(ema: bytes, io_binding: bool) -> None:
    """A renderer's (H, W, 4) half-float RGBA and (H, W, 3) albedo: alpha ignored, same frames
    as planar float32 of the same values, output interleaved like `color`."""
    planar = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    den = Denoiser(ema, fast_kernels=False, io_binding=io_binding)
    rng = np.random.default_rng(1)
    for color, albedo in zip(frames(3, 10, 13), frames(3, 10, 13, 1), strict=True):
        rgba = np.concatenate([color.transpose(1, 2, 0), rng.random((10, 13, 1))], axis=2)
        rgba = rgba.astype(np.float16)
        out = den.process({"color": rgba, "albedo": albedo.transpose(1, 2, 0)})
        expected = planar.process({"color": rgba[..., :3].transpose(2, 0, 1), "albedo": albedo})
        assert out.shape == (10, 13, 3) and out.dtype == np.float32 and out.flags.c_contiguous
        np.testing.assert_array_equal(out, expected.transpose(1, 2, 0))
    assert den.frame_index == 3


def test_out_arrays_are_filled_in_place(ema: bytes) -> None:
    den = Denoiser(ema, fast_kernels=False)
    ref = Denoiser(ema, fast_kernels=False)
    color, albedo = frames(1, 9, 11)[0], frames(1, 9, 11, 1)[0]
    expected = ref.process({"color": color, "albedo": albedo})
    rgba = np.full((9, 11, 4), 7.0, np.float32)  # an RGBA framebuffer: alpha stays 7
    assert den.process({"color": color, "albedo": albedo}, out=rgba) is rgba
    np.testing.assert_array_equal(rgba[..., :3], expected.transpose(1, 2, 0))
    assert (rgba[..., 3] == 7.0).all()
    half = np.zeros((3, 9, 11), np.float16)  # a half-float target clamps, never overflows
    big = Denoiser(blowup_model(), fast_kernels=False)  # 1e30 on its second frame
    big.process({"color": color}, out=half)
    big.process({"color": color}, out=half)
    assert np.isfinite(half).all() and half.max() == np.float16(65504)
    for bad, match in [
        (np.zeros((9, 11, 2), np.float32), r"out has shape \(9, 11, 2\); expected \(3, 9, 11\)"),
        (np.zeros((3, 9, 11), np.float64), "out must be a float32 or float16 numpy array"),
        ([[0.0]], "got list"),
    ]:
        with pytest.raises(InputError, match=match):
            den.process({"color": color, "albedo": albedo}, out=bad)


def test_read_only_out_is_refused_before_the_frame_runs(ema: bytes) -> None:
    """Issue 27, item 6: a read-only `out` used to fail after the frame ran, losing that
    frame's history. Now refused first: the history (frame_index, state) is untouched."""
    den = Denoiser(ema, fast_kernels=False)
    ref = Denoiser(ema, fast_kernels=False)
    seq = [(c, a) for c, a in zip(frames(3, 9, 11), frames(3, 9, 11, 1), strict=True)]
    for c, a in seq[:2]:
        den.process({"color": c, "albedo": a})
        ref.process({"color": c, "albedo": a})
    for layout in [(3, 9, 11), (9, 11, 3), (9, 11, 4)]:
        locked = np.zeros(layout, np.float32)
        locked.flags.writeable = False
        with pytest.raises(InputError, match=r"out is a read-only array \(shape"):
            den.process({"color": seq[2][0], "albedo": seq[2][1]}, out=locked)
    assert den.frame_index == ref.frame_index == 2
    c, a = seq[2]
    np.testing.assert_array_equal(
        den.process({"color": c, "albedo": a}), ref.process({"color": c, "albedo": a})
    )


def test_layout_tie_and_forced_channels_last(ema: bytes) -> None:
    """(3, 8, 3) fits planar (a 3-pixel-wide frame) and interleaved (3 pixels tall): planar
    unless channels_last=True; interleaved depth may be (H, W)."""
    from rtdenoise.runtime.arrays import is_interleaved

    den = Denoiser(ema, fast_kernels=False)
    tie = np.ones((3, 8, 3), np.float32)
    assert den.process({"color": tie, "albedo": tie}).shape == (3, 8, 3)
    out = den.process({"color": tie, "albedo": tie}, channels_last=True)
    assert out.shape == (3, 8, 3) and den.frame_index == 1  # 3x8 frames: a new history
    assert is_interleaved(np.zeros((5, 7)), 1, None)
    assert not is_interleaved(np.zeros((1, 5, 7)), 1, None)
    assert not is_interleaved(np.zeros((5, 7, 3)), 3, False)
    with pytest.raises(InputError, match=r"or \(H, W, 3\[\+alpha\]\), float32 or float16"):
        den.process({"color": np.zeros((8, 8, 5), np.float32), "albedo": tie})
