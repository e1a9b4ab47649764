"""Augmentation (models/augment.py, models/data.py): flips, quarter turns and colour permutation
keep motion vectors, camera-space normals, depth and colours consistent with the image."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from rtdenoise.models.augment import Transform, apply_transform, permutations
from rtdenoise.models.data import ClipSampler, SequenceData
from rtdenoise.models.ops.reproject import reproject
from rtdenoise.models.temporal import in_bounds
from rtdenoise.models.transfer import autoexposure

# The 8 symmetries of the square (the dihedral group) x the 6 colour permutations.
FLIPS = itertools.product((False, True), (False, True), range(4))
GEOMETRIC = [Transform(h, v, k) for h, v, k in FLIPS]
ALL = [Transform(t.flip_h, t.flip_v, t.rotation, p) for t in GEOMETRIC for p in permutations()]


def _pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """An RGB pattern with no symmetry (x right, y down, in pixels)."""
    return np.stack(
        [
            np.sin(0.37 * x + 0.11 * y) + 0.3 * np.cos(0.05 * x * y),
            np.cos(0.21 * x - 0.43 * y + 1.0),
            0.5 * np.sin(0.17 * (x + 2 * y)) + 0.01 * x,
        ]
    ).astype(np.float32)


def _translating_clip(size: int = 24, velocity=(2, -1)):
    """Two frames of a pattern moving by `velocity` px per frame (image coordinates), its
    motion (previous = current + motion: -velocity), and a colour buffer alike."""
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32)
    vx, vy = velocity
    frames = np.stack([_pattern(xs - vx * t, ys - vy * t) for t in range(2)])  # (2, 3, H, W)
    motion = np.zeros((2, 2, size, size), np.float32)
    motion[:, 0], motion[:, 1] = -vx, -vy
    return frames, motion


def test_translating_pattern_warps_onto_itself_under_every_transform():
    frames, motion = _translating_clip()
    prev, cur = torch.from_numpy(frames[:1]), torch.from_numpy(frames[1:])
    m = torch.from_numpy(motion[1:])
    mask = in_bounds(m)
    # the construction: warping the previous frame gives the current one where it is visible
    np.testing.assert_allclose(
        (reproject(prev, m) * mask).numpy(), (cur * mask).numpy(), atol=1e-5, rtol=0
    )
    for t in ALL:
        bufs, ref = apply_transform({"color": frames, "motion": motion}, frames, t)
        aprev, acur = torch.from_numpy(bufs["color"][:1]), torch.from_numpy(bufs["color"][1:])
        am = torch.from_numpy(bufs["motion"][1:])
        amask = in_bounds(am)
        assert amask.float().mean() > 0.8, t
        warped = reproject(aprev, am) * amask
        np.testing.assert_allclose(warped.numpy(), (acur * amask).numpy(), atol=1e-5, err_msg=t)
        np.testing.assert_array_equal(ref, bufs["color"])  # reference transformed alike
    # a wrong sign convention would not pass: rotate motion as if y pointed up
    t = Transform(rotation=1)
    bufs, _ = apply_transform({"color": frames, "motion": motion}, frames, t)
    wrong = torch.from_numpy(-bufs["motion"][1:])
    ok = in_bounds(wrong)
    err = (
        reproject(torch.from_numpy(bufs["color"][:1]), wrong) - torch.from_numpy(bufs["color"][1:])
    ) * ok
    assert float(err.abs().max()) > 0.1


def test_transforms_commute_with_reprojection_of_any_motion_field():
    g = torch.Generator().manual_seed(5)
    prev = torch.rand(1, 3, 16, 16, generator=g)
    motion = (torch.rand(1, 2, 16, 16, generator=g) - 0.5) * 6.0
    warped = reproject(prev, motion).numpy()
    mask = in_bounds(motion).numpy()
    for t in GEOMETRIC:
        bufs, ref = apply_transform({"color": prev.numpy(), "motion": motion.numpy()}, warped, t)
        out = reproject(torch.from_numpy(bufs["color"]), torch.from_numpy(bufs["motion"]))
        np.testing.assert_allclose(out.numpy(), ref, atol=1e-5, rtol=0, err_msg=str(t))
        tmask = in_bounds(torch.from_numpy(bufs["motion"])).numpy()
        np.testing.assert_array_equal(tmask, apply_transform({}, mask, Transform(*astuple(t)))[1])


def astuple(t: Transform) -> tuple:
    return (t.flip_h, t.flip_v, t.rotation)


def _heightfield_normals(h: np.ndarray) -> np.ndarray:
    """Camera-space normals (x right, y up, z towards the camera) of a surface facing the
    camera whose distance to it grows by h (pixels): n ~ (-dh/dx, -dh/dy_up, 1)."""
    dy_down, dx = np.gradient(h)
    n = np.stack([-dx, dy_down, np.ones_like(h)])  # dh/dy_up = -dh/dy_down
    return (n / np.linalg.norm(n, axis=0)).astype(np.float32)


def test_normals_follow_the_geometry_and_depth_is_unchanged():
    ys, xs = np.mgrid[0:20, 0:20].astype(np.float32)
    height = 3.0 * np.exp(-((xs - 6.0) ** 2 / 18.0 + (ys - 13.0) ** 2 / 8.0)) + 0.05 * xs
    depth = (5.0 + height)[None]
    normal = _heightfield_normals(height)
    for t in ALL:
        bufs, _ = apply_transform({"normal": normal, "depth": depth}, normal, t)
        moved = bufs["depth"][0] - 5.0  # the transformed surface
        np.testing.assert_allclose(bufs["normal"], _heightfield_normals(moved), atol=1e-5)
        assert sorted(bufs["depth"].ravel()) == sorted(depth.ravel())  # values only move
        np.testing.assert_allclose(np.linalg.norm(bufs["normal"], axis=0), 1.0, atol=1e-6)
    # treating normals as y-down vectors would break it on a quarter turn
    bufs, _ = apply_transform({"normal": normal, "depth": depth}, normal, Transform(rotation=1))
    wrong = bufs["normal"].copy()
    wrong[:2] *= -1
    assert np.abs(wrong - _heightfield_normals(bufs["depth"][0] - 5.0)).max() > 0.1


def test_colour_permutation_is_shared_and_skips_normals():
    rng = np.random.default_rng(0)
    names = (("color", 3), ("color_b", 3), ("albedo", 3), ("normal", 3), ("depth", 1))
    arrays = {n: rng.random((2, c, 8, 8), dtype=np.float32) for n, c in names}
    ref = rng.random((2, 3, 8, 8), dtype=np.float32)
    features = ("color", "albedo", "normal", "depth")
    samples = rng.random((2, 4, 10, 8, 8), dtype=np.float32)
    arrays["samples"] = samples
    p = (2, 0, 1)
    out, oref = apply_transform(arrays, ref, Transform(permutation=p), features)
    for n in ("color", "color_b", "albedo"):
        np.testing.assert_array_equal(out[n], arrays[n][:, list(p)])
    np.testing.assert_array_equal(oref, ref[:, list(p)])
    np.testing.assert_array_equal(out["normal"], arrays["normal"])
    np.testing.assert_array_equal(out["depth"], arrays["depth"])
    np.testing.assert_array_equal(out["samples"][:, :, 0:3], samples[:, :, list(p)])
    np.testing.assert_array_equal(out["samples"][:, :, 3:6], samples[:, :, [3 + c for c in p]])
    np.testing.assert_array_equal(out["samples"][:, :, 6:], samples[:, :, 6:])
    # per-sample normals turn like the pixel normals
    t = Transform(flip_h=True, rotation=3)
    pix, _ = apply_transform({"normal": samples[:, 1, 6:9]}, ref, t)
    per, _ = apply_transform({"samples": samples}, ref, t, features)
    np.testing.assert_array_equal(per["samples"][:, 1, 6:9], pix["normal"])


def test_group_relations():
    rng = np.random.default_rng(1)
    m = rng.random((1, 2, 6, 6), dtype=np.float32)
    n = rng.random((1, 3, 6, 6), dtype=np.float32)

    def go(t: Transform):
        return apply_transform({"motion": m, "normal": n}, n, t)[0]

    for a, b in (
        (Transform(rotation=2), Transform(True, True)),
        (Transform(rotation=4), Transform()),
        (Transform(True, False, 1), Transform(False, True, 3)),
    ):
        ga, gb = go(a), go(b)
        for k in ga:
            np.testing.assert_array_equal(ga[k], gb[k])


def _old_clip(seq: SequenceData, rng: np.random.Generator, frames: int, crop: int, scale_range):
    """The draws of the sampler before rotations / permutation / exposure existed."""
    t0 = int(rng.integers(seq.frames - frames + 1))
    y0 = int(rng.integers(seq.size[0] - crop + 1))
    x0 = int(rng.integers(seq.size[1] - crop + 1))
    fh, fv = (bool(b) for b in rng.integers(2, size=2))
    scale = float(rng.uniform(*scale_range))
    w = (slice(t0, t0 + frames), Ellipsis, slice(y0, y0 + crop), slice(x0, x0 + crop))
    out, _ = apply_transform(
        {"color": seq.buffers["color"][w]}, seq.reference[w], Transform(fh, fv)
    )
    return out["color"] * np.float32(scale)


def _seq(scale: float = 1.0, seed: int = 0) -> SequenceData:
    rng = np.random.default_rng(seed)
    color = rng.exponential(0.3, (4, 3, 20, 20)).astype(np.float32) * scale
    return SequenceData(
        "s",
        {"color": color, "albedo": np.full((4, 3, 20, 20), 0.5, np.float32)},
        (color * 0.9).astype(np.float32),
    )


def test_sampler_draws_every_transform_and_keeps_the_old_stream_when_off():
    seq = _seq()
    rng = np.random.default_rng(4)
    sampler = ClipSampler([seq], rng, frames=2, crop=12, batch=1, rotations=True, permute=True)
    seen_turns, seen_perm = set(), set()
    for _ in range(60):
        state = rng.bit_generator.state
        sampler.clip()
        probe = np.random.default_rng()
        probe.bit_generator.state = state
        draws = [int(probe.integers(1)), int(probe.integers(3)), int(probe.integers(9)),
                 int(probe.integers(9))]  # fmt: skip
        probe.integers(2, size=2), probe.uniform(0.8, 1.2)
        seen_turns.add(int(probe.integers(4)))
        seen_perm.add(int(probe.integers(6)))
        assert draws[0] == 0
    assert seen_turns == {0, 1, 2, 3} and seen_perm == set(range(6))
    # all new options off: the clips of the sampler before they existed, bit for bit
    a, b = np.random.default_rng(9), np.random.default_rng(9)
    plain = ClipSampler([seq], a, frames=3, crop=16, batch=1)
    for _ in range(5):
        got, _ = plain.clip()
        b.integers(1)  # the sequence index
        np.testing.assert_array_equal(got["color"], _old_clip(seq, b, 3, 16, (0.8, 1.2)))


def test_auto_exposure_normalises_clips_of_any_brightness():
    clips = []
    for scale in (1.0, 20.0):
        sampler = ClipSampler(
            [_seq(scale)], np.random.default_rng(2), frames=4, crop=20, batch=1, flips=False,
            brightness=(1.0, 1.0), exposure="auto",
        )  # fmt: skip
        clips.append(sampler.clip())
    (b1, r1), (b2, r2) = clips
    np.testing.assert_allclose(b1["color"], b2["color"], rtol=1e-5)
    np.testing.assert_allclose(r1, r2, rtol=1e-5)
    # the clip's exposure is now 1 (its block-luminance geometric mean is the key 0.18)
    e = autoexposure(torch.from_numpy(b1["color"])[None])
    assert abs(float(e[0]) - 1.0) < 1e-4
    # colour and reference scaled by the same factor, albedo untouched
    seq = _seq()
    np.testing.assert_allclose(r1 / b1["color"], seq.reference / seq.buffers["color"], rtol=1e-5)
    np.testing.assert_array_equal(b1["albedo"], seq.buffers["albedo"])
    with pytest.raises(Exception, match="exposure"):
        ClipSampler([seq], np.random.default_rng(0), exposure="bright")
