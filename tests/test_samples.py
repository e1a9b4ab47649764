"""Per-sample input (the contract's rank-5 `samples` buffer): EXR sample layers, S = 1 from the
pixel means, the frame reader's hook, the clip sampler (crops, flips, brightness and sample
counts on the extra axis), and the renderer's `--samples`."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from rtdenoise.models.data import ClipSampler, SequenceData, flip
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr, write_exr
from rtdenoise.runtime.sequences.frames import read_frame
from rtdenoise.runtime.sequences.samples import (
    DEFAULT_SAMPLE_FEATURES,
    feature_channels,
    read_samples,
    sample_channels,
    sample_count,
    samples_from_buffers,
)

FEATURES = DEFAULT_SAMPLE_FEATURES  # color, albedo, normal, depth: C = 10
H, W = 6, 7


def _frame_channels(rng, s: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Canonical pixel channels plus `s` sample layers; returns (channels, samples)."""
    samples = rng.random((s, 10, H, W), dtype=np.float32)
    channels = {}
    for i in range(s):
        c = 0
        for f in FEATURES:
            for name in sample_channels(i, f):
                channels[name] = samples[i, c]
                c += 1
    mean = samples[:, :3].mean(axis=0)
    for k, ch in enumerate("RGB"):
        channels[ch] = mean[k]
        channels[f"albedo.{ch}"] = rng.random((H, W), dtype=np.float32)
    for ch in "XYZ":
        channels[f"normal.{ch}"] = rng.random((H, W), dtype=np.float32)
    channels["depth.Z"] = rng.random((H, W), dtype=np.float32) + 1
    channels["motion.X"] = channels["motion.Y"] = np.zeros((H, W), np.float32)
    return channels, samples


def test_sample_layer_names_and_count():
    assert feature_channels(FEATURES) == 10
    assert sample_channels(0, "color") == ["sample0.R", "sample0.G", "sample0.B"]
    assert sample_channels(3, "normal") == [
        "sample3.normal.X",
        "sample3.normal.Y",
        "sample3.normal.Z",
    ]
    assert sample_channels(1, "depth") == ["sample1.depth.Z"]
    assert sample_count(["R", "sample0.R", "sample1.R", "sample3.R"]) == 2  # consecutive only
    with pytest.raises(InputError, match="distinct canonical buffers other than motion"):
        feature_channels(("color", "motion"))


def test_frames_with_and_without_sample_layers(tmp_path):
    rng = np.random.default_rng(0)
    channels, samples = _frame_channels(rng, 3)
    write_exr(tmp_path / "frame_0000.exr", channels, half=False)
    frame = read_frame(tmp_path / "frame_0000.exr", sample_features=FEATURES)
    np.testing.assert_array_equal(frame.buffers["samples"], samples)
    np.testing.assert_allclose(frame.buffers["color"], samples[:, :3].mean(axis=0), rtol=1e-6)
    assert "samples" not in read_frame(tmp_path / "frame_0000.exr").buffers  # only when asked
    # a file with pixel buffers only: S = 1 from the pixel means
    plain = {k: v for k, v in channels.items() if not k.startswith("sample")}
    write_exr(tmp_path / "frame_0001.exr", plain, half=False)
    frame = read_frame(tmp_path / "frame_0001.exr", sample_features=FEATURES)
    b = frame.buffers
    assert b["samples"].shape == (1, 10, H, W)
    expected = np.concatenate([b["color"], b["albedo"], b["normal"], b["depth"]])
    np.testing.assert_array_equal(b["samples"][0], expected)
    np.testing.assert_array_equal(samples_from_buffers(b, ("color", "depth"))[0, 3], b["depth"][0])


def test_sample_layer_errors_and_nonfinite(tmp_path):
    rng = np.random.default_rng(1)
    channels, _ = _frame_channels(rng, 2)
    broken = {k: v for k, v in channels.items() if k != "sample1.normal.Y"}
    with pytest.raises(InputError, match="sample1.normal.Y"):
        read_samples(broken, FEATURES, "f.exr")
    bad = dict(channels)
    bad["sample1.depth.Z"] = bad["sample1.depth.Z"].copy()
    bad["sample1.depth.Z"][2, 3] = np.nan
    write_exr(tmp_path / "frame_0000.exr", bad, half=False)
    frame = read_frame(tmp_path / "frame_0000.exr", sample_features=FEATURES)
    assert frame.nonfinite == 1 and frame.nonfinite_buffers == ("samples",)
    assert (
        frame.buffers["samples"][1, 9, 2, 3] == 0.0 and np.isfinite(frame.buffers["samples"]).all()
    )


def _sequence(s: int, name: str, seed: int) -> SequenceData:
    rng = np.random.default_rng(seed)
    t, h, w = 3, 8, 10
    samples = rng.random((t, s, 10, h, w), dtype=np.float32)
    normal = rng.random((t, 3, h, w), dtype=np.float32)
    return SequenceData(
        name,
        {"samples": samples, "normal": normal, "motion": rng.random((t, 2, h, w), np.float32)},
        rng.random((t, 3, h, w), dtype=np.float32),
    )


def test_flips_and_brightness_treat_the_sample_axis():
    seq = _sequence(4, "a", 0)
    samples, normal = seq.buffers["samples"], seq.buffers["normal"]
    out, ref = flip(seq.buffers, seq.reference, True, True, FEATURES)
    expected = samples[..., ::-1, ::-1].copy()
    expected[:, :, 6:8] *= -1  # normal.x and normal.y of every sample
    np.testing.assert_array_equal(out["samples"], expected)
    np.testing.assert_array_equal(out["normal"][:, :2], -normal[:, :2, ::-1, ::-1])
    np.testing.assert_array_equal(ref, seq.reference[..., ::-1, ::-1])
    # a crop of the whole width and height, no flips, brightness 2: radiance channels doubled
    square = SequenceData("b", {"samples": samples[..., :8, :8]}, seq.reference[..., :8, :8])
    sampler = ClipSampler(
        [square], np.random.default_rng(0), frames=3, crop=8, batch=1, flips=False,
        brightness=(2.0, 2.0), sample_features=FEATURES,
    )  # fmt: skip
    got = sampler.sample().buffers["samples"][0].numpy()
    assert got.shape == (3, 4, 10, 8, 8)
    np.testing.assert_allclose(got[:, :, :3], 2.0 * samples[:, :, :3, :8, :8])
    np.testing.assert_array_equal(got[:, :, 3:], samples[:, :, 3:, :8, :8])


def test_clip_sampler_draws_sample_counts_and_equalises_them():
    seqs = [_sequence(4, "four", 1), _sequence(1, "one", 2)]
    rng = np.random.default_rng(0)
    sampler = ClipSampler(
        seqs, rng, frames=2, crop=8, batch=2, sample_counts=(1, 2, 4), sample_features=FEATURES
    )
    seen = set()
    for _ in range(30):
        b = sampler.sample()
        s = b.buffers["samples"].shape[2]
        seen.add(s)
        assert b.buffers["samples"].shape[:2] == (2, 2) and s in (1, 2, 4)
    assert seen == {1, 2, 4}
    with pytest.raises(InputError, match="sample counts must be >= 1"):
        ClipSampler(seqs, rng, sample_counts=(0,))


@pytest.mark.skipif(importlib.util.find_spec("mitsuba") is None, reason="mitsuba not installed")
def test_renderer_writes_independent_samples(tmp_path):
    from rtdenoise.datagen.render import RenderConfig, render_sequence
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")
    cfg = RenderConfig(12, 10, 2, spp_ref=4, half=False, samples=3)
    meta = render_sequence(tmp_path, 7, cfg, variant="scalar_rgb")
    assert meta["samples"] == 3 and meta["spp"]["color"] == 3
    ch = read_exr(tmp_path / "frame_0001.exr")
    assert sample_count(ch) == 3
    s = read_samples(ch, FEATURES)
    assert s.shape == (3, 10, 10, 12) and np.isfinite(s).all()
    color = np.stack([ch[c] for c in "RGB"])
    np.testing.assert_allclose(s[:, :3].mean(axis=0), color, rtol=1e-5, atol=1e-6)  # the mean
    assert not np.allclose(s[0, :3], s[1, :3])  # independent samples
    n = np.linalg.norm(s[:, 6:9], axis=1)
    assert np.all((np.abs(n - 1) < 2e-3) | (n == 0)) and (s[:, 9] > 0).all()


def test_sequence_plan_reads_samples_for_a_per_sample_model(tmp_path):
    """`plan_sequence` / `iter_sequence` with a model's buffers: the first frame's sample
    layers in every frame (a frame without them is refused by name), else S = 1."""
    from rtdenoise.runtime.sequences.frames import iter_sequence
    from rtdenoise.shipped import sample_sequences

    rng = np.random.default_rng(4)
    expected = []
    for t in range(2):
        channels, samples = _frame_channels(rng, 2)
        write_exr(tmp_path / f"frame_{t:04d}.exr", channels, half=False)
        expected.append(samples)
    frames = list(iter_sequence(tmp_path, buffers=("samples", "motion"), sample_features=FEATURES))
    assert [sorted(f.buffers) for f in frames] == [["color", "motion", "samples"]] * 2
    for frame, samples in zip(frames, expected, strict=True):
        np.testing.assert_array_equal(frame.buffers["samples"], samples)
    channels, _ = _frame_channels(rng, 1)  # a third frame with one sample only
    write_exr(tmp_path / "frame_0002.exr", channels, half=False)
    with pytest.raises(InputError, match="frame_0002.exr: missing channel sample1"):
        list(iter_sequence(tmp_path, buffers=("samples", "motion"), sample_features=FEATURES))
    committed = sample_sequences()[0]  # pixel buffers only: S = 1 from the pixel means
    frame = next(iter_sequence(committed, buffers=("samples", "motion")))
    assert frame.buffers["samples"].shape == (1, 10, 64, 64)
    np.testing.assert_array_equal(frame.buffers["samples"][0, :3], frame.buffers["color"])
