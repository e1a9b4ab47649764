"""Reprojection, history validity and accumulation (models/temporal.py), and flip augmentation."""

from __future__ import annotations

import numpy as np
import torch

from rtdenoise.models.data import flip
from rtdenoise.models.ops.temporal_accumulation import temporal_accumulation
from rtdenoise.models.temporal import (
    TemporalConfig,
    accumulate,
    history_validity,
    in_bounds,
    reproject,
)

H, W = 12, 16


def _const_motion(dx: float, dy: float, n: int = 1) -> torch.Tensor:
    m = torch.zeros(n, 2, H, W)
    m[:, 0] = dx
    m[:, 1] = dy
    return m


def _flat_geometry(n: int = 1, depth: float = 2.0) -> tuple[torch.Tensor, torch.Tensor]:
    normal = torch.zeros(n, 3, H, W)
    normal[:, 2] = 1.0
    return normal, torch.full((n, 1, H, W), depth)


def test_integer_shift_moves_image_exactly():
    prev = torch.rand(2, 3, H, W, generator=torch.Generator().manual_seed(0))
    out = reproject(prev, _const_motion(2.0, -1.0, n=2))
    # previous = current + motion: out[y, x] = prev[y - 1, x + 2] where that pixel exists.
    torch.testing.assert_close(out[:, :, 1:, : W - 2], prev[:, :, : H - 1, 2:], atol=1e-6, rtol=0)
    mask = in_bounds(_const_motion(2.0, -1.0))[0, 0]
    assert not mask[0].any()  # row y = 0 reads row -1
    assert not mask[:, W - 2 :].any()  # x + 2 >= W
    assert mask[1:, : W - 2].all()
    assert int(mask.sum()) == (H - 1) * (W - 2)


def test_fractional_shift_is_bilinear():
    prev = torch.rand(1, 1, H, W, generator=torch.Generator().manual_seed(1))
    out = reproject(prev, _const_motion(0.25, 0.5))
    a, b = prev[..., : H - 1, : W - 1], prev[..., : H - 1, 1:]
    c, d = prev[..., 1:, : W - 1], prev[..., 1:, 1:]
    expected = 0.5 * (0.75 * a + 0.25 * b) + 0.5 * (0.75 * c + 0.25 * d)
    torch.testing.assert_close(out[..., : H - 1, : W - 1], expected, atol=1e-6, rtol=0)


def test_depth_and_normal_mismatch_are_invalid():
    normal, depth = _flat_geometry()
    prev_normal, prev_depth = normal.clone(), depth.clone()
    prev_depth[..., 2:4, 3:6] = 2.5  # 25 % farther: another surface
    prev_depth[..., 8, 8] = 2.1  # 5 %: within the 10 % tolerance
    prev_normal[..., 6:9, 10:12] = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)  # 90 degrees
    motion = _const_motion(0.0, 0.0)
    valid = history_validity(motion, depth, normal, prev_depth, prev_normal, torch.tensor(0.0))
    expected = torch.ones(1, 1, H, W)
    expected[..., 2:4, 3:6] = 0.0
    expected[..., 6:9, 10:12] = 0.0
    torch.testing.assert_close(valid, expected, atol=0, rtol=0)
    # reset = 1 rejects everything, arithmetically.
    valid = history_validity(motion, depth, normal, prev_depth, prev_normal, torch.tensor(1.0))
    assert float(valid.abs().sum()) == 0.0


def test_out_of_screen_is_invalid():
    normal, depth = _flat_geometry()
    motion = _const_motion(-3.0, 0.0)
    valid = history_validity(motion, depth, normal, depth, normal, torch.tensor(0.0))
    assert float(valid[..., :3].sum()) == 0.0
    assert float(valid[..., 3:].min()) == 1.0


def test_accumulation_weights():
    cur = torch.full((1, 3, H, W), 1.0)
    hist = torch.full((1, 3, H, W), 3.0)
    valid = torch.ones(1, 1, H, W)
    valid[..., 0, 0] = 0.0
    length = torch.full((1, 1, H, W), 1.0)
    length[..., 5, 5] = 10.0
    acc, new_len, alpha = accumulate(cur, hist, length, valid, TemporalConfig(min_alpha=0.2))
    assert float(acc[0, 0, 1, 1]) == 2.0  # a = 1 / (1 + 1): mean of two frames
    assert abs(float(acc[0, 0, 5, 5]) - (0.2 * 1.0 + 0.8 * 3.0)) < 1e-6  # a = min_alpha
    assert float(acc[0, 0, 0, 0]) == 1.0  # invalid: current only
    assert float(new_len[0, 0, 0, 0]) == 1.0 and float(new_len[0, 0, 1, 1]) == 2.0
    assert float(alpha[0, 0, 0, 0]) == 1.0


def test_reset_gives_current_only_even_with_nonfinite_history():
    normal, depth = _flat_geometry()
    cur = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(2))
    ta_state = torch.full((1, 4, H, W), float("nan"))
    geometry = torch.cat((normal, depth), dim=1)
    motion = _const_motion(0.0, 0.0)
    acc, blend, next_ta, next_geo = temporal_accumulation(
        cur, motion, depth, normal, ta_state, geometry, torch.tensor(1.0)
    )
    torch.testing.assert_close(acc, cur, atol=0, rtol=0)
    assert float(blend.min()) == 1.0
    torch.testing.assert_close(next_ta[:, 3:], torch.ones(1, 1, H, W))  # history length 1
    torch.testing.assert_close(next_geo, geometry)


def test_static_scene_accumulates_the_mean():
    normal, depth = _flat_geometry()
    geometry = torch.cat((normal, depth), dim=1)
    motion = _const_motion(0.0, 0.0)
    frames = [torch.full((1, 3, H, W), v) for v in (1.0, 2.0, 6.0)]
    ta = torch.zeros(1, 4, H, W)
    for i, cur in enumerate(frames):
        acc, _, ta, geometry = temporal_accumulation(
            cur, motion, depth, normal, ta, geometry, torch.tensor(1.0 if i == 0 else 0.0)
        )
    torch.testing.assert_close(acc, torch.full_like(acc, 3.0))  # (1 + 2 + 6) / 3
    torch.testing.assert_close(ta[:, 3:], torch.full((1, 1, H, W), 3.0))


def _random_motion(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(1, 2, H, W, generator=g) - 0.5) * 5.0


def test_flip_augmentation_commutes_with_reprojection():
    g = torch.Generator().manual_seed(3)
    prev = torch.rand(1, 3, H, W, generator=g)
    motion = _random_motion(4)
    normal = torch.nn.functional.normalize(torch.randn(1, 3, H, W, generator=g), dim=1)
    warped = reproject(prev, motion)
    mask = in_bounds(motion)
    for horizontal, vertical in ((True, False), (False, True), (True, True)):
        bufs = {"color": prev.numpy(), "motion": motion.numpy(), "normal": normal.numpy()}
        ref = warped.numpy()
        fb, fref = flip(bufs, ref, horizontal, vertical)
        # motion / normal: the flipped component changes sign, the other is untouched
        axes = tuple(a for a, on in ((-1, horizontal), (-2, vertical)) if on)
        m = np.flip(motion.numpy(), axis=axes)
        assert np.array_equal(fb["motion"][:, 0], -m[:, 0] if horizontal else m[:, 0])
        assert np.array_equal(fb["motion"][:, 1], -m[:, 1] if vertical else m[:, 1])
        assert np.array_equal(fb["color"], np.flip(prev.numpy(), axis=axes))
        # reprojecting the flipped previous frame with flipped motion = flipped reprojection
        out = reproject(torch.from_numpy(fb["color"]), torch.from_numpy(fb["motion"]))
        np.testing.assert_allclose(out.numpy(), fref, atol=1e-5, rtol=0)
        fmask = in_bounds(torch.from_numpy(fb["motion"])).numpy()
        assert np.array_equal(fmask, np.flip(mask.numpy(), axis=axes))
        # normal x / y change sign like motion; the agreement test (a dot product between
        # two normal fields flipped alike) is unchanged
        nf = fb["normal"]
        n0 = np.flip(normal.numpy(), axis=axes)
        assert np.array_equal(nf[:, 0], -n0[:, 0] if horizontal else n0[:, 0])
        assert np.array_equal(nf[:, 1], -n0[:, 1] if vertical else n0[:, 1])
        assert np.array_equal(nf[:, 2], n0[:, 2])
        other, _ = flip({"normal": np.roll(normal.numpy(), 1, axis=-1)}, ref, horizontal, vertical)
        dots = (nf * other["normal"]).sum(1)
        expected = np.flip((normal.numpy() * np.roll(normal.numpy(), 1, axis=-1)).sum(1), axes)
        np.testing.assert_allclose(dots, expected, atol=1e-6)


def test_per_tap_keeps_the_foreground_taps_at_a_silhouette():
    """SVGF's per-tap test (TemporalConfig.per_tap=1): half a pixel from a depth edge, the
    bilinear scheme tests the interpolated depth (2 and 8 -> 5) and drops the history of a
    foreground pixel; per tap keeps its foreground tap, renormalised to weight 1. Where every
    tap agrees both give the bilinear history; gradients reach the history."""
    normal, depth = _flat_geometry()
    prev_depth = depth.clone()
    prev_depth[..., W // 2 :] = 8.0  # the background, right half
    depth = prev_depth.clone()  # the same silhouette this frame
    history = torch.where(prev_depth > 4.0, 5.0, 1.0).expand(1, 3, H, W).clone()
    ta_state = torch.cat((history, torch.full((1, 1, H, W), 4.0)), dim=1).requires_grad_(True)
    geometry = torch.cat((normal, prev_depth), dim=1)
    current = torch.zeros(1, 3, H, W)
    motion = _const_motion(0.5, 0.0)
    outs = {}
    for per_tap in (0, 1):
        config = TemporalConfig(per_tap=per_tap)
        outs[per_tap] = temporal_accumulation(
            current, motion, depth, normal, ta_state, geometry, torch.tensor(0.0), config
        )
    edge = W // 2 - 1  # foreground pixel whose right tap is background
    assert float(outs[0][1][0, 0, 3, edge].detach()) == 1.0  # bilinear: history dropped
    alpha = float(outs[1][1][0, 0, 3, edge].detach())
    assert alpha == np.float32(0.2)  # per tap: history length 4 kept
    torch.testing.assert_close(outs[1][0][0, :, 3, edge].detach(), torch.full((3,), 0.8))
    inner = slice(0, edge - 1)
    torch.testing.assert_close(
        outs[1][0][..., inner].detach(), outs[0][0][..., inner].detach(), atol=1e-6, rtol=0
    )
    outs[1][0].sum().backward()
    assert ta_state.grad is not None and float(ta_state.grad[:, :3].abs().sum()) > 0
