"""Tests of the Mitsuba data generator (rtdenoise.datagen) and `denoise-render`.

numpy-only parts (camera model, features, warp check, committed sequences) always
run; rendering tests skip when mitsuba (the optional `[data]` extra) is missing.
"""

from __future__ import annotations

import importlib.util
import json
import math

import numpy as np
import OpenEXR
import pytest

from rtdenoise.datagen.camera import Camera, pixel_centres, pixel_directions, project
from rtdenoise.datagen.features import camera_space_normals, motion_vectors, override_albedo
from rtdenoise.datagen.render import RenderConfig, derive_seed, sanitize
from rtdenoise.datagen.validate import psnr, tonemap, warp_gain_db, warp_previous, warp_report
from rtdenoise.runtime.sequences.exr import read_exr, write_exr
from rtdenoise.shipped import sample_sequences

HAS_MITSUBA = importlib.util.find_spec("mitsuba") is not None
needs_mitsuba = pytest.mark.skipif(not HAS_MITSUBA, reason="mitsuba not installed ([data] extra)")

FRAME_CHANNELS = {
    "R", "G", "B", "colorB.R", "colorB.G", "colorB.B", "albedo.R", "albedo.G", "albedo.B",
    "normal.X", "normal.Y", "normal.Z", "depth.Z", "motion.X", "motion.Y",
}  # fmt: skip


# ----------------------------------------------------------------- committed test set


def test_committed_sequences_layout():
    seqs = sample_sequences()
    assert [s.name for s in seqs] == ["seq_000", "seq_001", "seq_002"]
    total = sum(f.stat().st_size for s in seqs for f in s.iterdir())
    assert total < 3_000_000
    for seq in seqs:
        meta = json.loads((seq / "meta.json").read_text())
        assert meta["resolution"] == [64, 64] and meta["frame_count"] == 8
        assert len(meta["cameras"]) == 8
        frame, ref = read_exr(seq / "frame_0003.exr"), read_exr(seq / "ref_0003.exr")
        assert set(frame) == FRAME_CHANNELS and set(ref) == {"R", "G", "B"}
        assert all(a.shape == (64, 64) and np.isfinite(a).all() for a in frame.values())
        noisy = np.stack([frame[c] for c in "RGB"], -1)
        clean = np.stack([ref[c] for c in "RGB"], -1)
        assert 0.05 < clean.mean() < 3.0  # neither black nor blown out
        # the 1-spp input is far noisier than the reference
        assert 8.0 < psnr(tonemap(noisy), tonemap(clean)) < 27.0
        assert 0.0 <= frame["albedo.R"].min() and frame["albedo.G"].max() <= 1.0


@pytest.mark.parametrize("index", [0, 1, 2])
def test_committed_motion_vectors_warp_references(index):
    seq = sample_sequences()[index]
    report = warp_report(seq)
    assert len(report) == 7
    assert all(r.valid_fraction > 0.4 for r in report)
    assert warp_gain_db(seq) > 5.0


# ----------------------------------------------------------------- numpy-only parts


def _cam(origin=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), w=16, h=12, fov=40.0) -> Camera:
    return Camera(tuple(origin), tuple(target), (0.0, 1.0, 0.0), fov, w, h)


def test_projection_of_pixel_rays_gives_pixel_centres():
    cam = Camera((1.0, 2.0, 4.0), (0.2, 0.3, -0.5), (0.0, 1.0, 0.0), 55.0, 20, 14)
    u, v, z = project(pixel_directions(cam), cam, directions=True)
    u0, v0 = pixel_centres(20, 14)
    np.testing.assert_allclose(u, u0, atol=1e-9)
    np.testing.assert_allclose(v, v0, atol=1e-9)
    assert (z > 0).all()
    # image right = camera -X (Mitsuba's +X is left): a point right of the target
    cam = _cam()
    u, v, _ = project(np.array([[1.0, 0.5, 0.0]]), cam)
    f = cam.focal_px
    assert u[0] == pytest.approx(8.0 + f * 1.0 / 5.0) and v[0] == pytest.approx(6.0 - f * 0.5 / 5.0)


def test_motion_of_a_plane_under_camera_translation():
    prev, cur = _cam((0.0, 0.0, 5.0), (0, 0, 0)), _cam((0.3, 0.0, 5.0), (0.3, 0, 0))
    d = pixel_directions(cur)
    t = 5.0 / -d[..., 2]  # hit the plane z = 0
    pos = np.asarray(cur.origin) + d * t[..., None]
    hit = np.ones((12, 16), bool)
    hit[0, 0] = False  # one background pixel: environment direction, no parallax
    mv = motion_vectors(pos, hit, cur, prev)
    expected = cur.focal_px * 0.3 / 5.0  # camera moved right: scene was further right before
    np.testing.assert_allclose(mv[1:, :, 0], expected, atol=1e-9)
    np.testing.assert_allclose(mv[..., 1], 0.0, atol=1e-9)
    assert mv[0, 0, 0] == pytest.approx(0.0, abs=1e-9)
    assert (motion_vectors(pos, hit, cur, None) == 0).all()


def test_camera_space_normals_face_the_camera():
    cam = _cam()
    facing = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (1, 4, 3))
    world = np.array([[[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1.0, 0]]])
    n = camera_space_normals(world, cam, facing)
    np.testing.assert_allclose(n[0, 0], [0, 0, 1], atol=1e-12)  # towards the camera: +z
    np.testing.assert_allclose(n[0, 1], [0, 0, 1], atol=1e-12)  # back face flipped
    np.testing.assert_allclose(n[0, 2], [1, 0, 0], atol=1e-12)  # world +X = image right
    np.testing.assert_allclose(n[0, 3], [0, 1, 0], atol=1e-12)


def test_override_albedo_and_sanitize():
    alb = np.full((2, 2, 3), 0.25)
    ids = np.array([[0, 1], [2, 7]])
    table = np.array([[np.nan] * 3, [0.9, 0.8, 0.1], [np.nan] * 3])
    out = override_albedo(alb, ids, table)
    np.testing.assert_allclose(out[0, 1], [0.9, 0.8, 0.1])
    np.testing.assert_allclose(out[[0, 1, 1], [0, 0, 1]], 0.25)  # keep, keep, out of range
    x, n = sanitize(np.array([1.0, np.nan, np.inf, -2.0, 1e6]), 65000.0)
    assert n == 2 and x.tolist() == [1.0, 0.0, 0.0, 0.0, 65000.0]
    assert derive_seed(1, 2) == derive_seed(1, 2) != derive_seed(2, 1)
    assert 0 <= derive_seed(7, 0) < 2**31


def _pattern(h: int, w: int, shift: float) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w] + 0.5
    x = x - shift
    return np.stack(
        [1 + np.sin(x / 3.0) * np.cos(y / 5.0), 0.5 + 0.3 * np.sin(x / 4.0), 0 * x + 0.3], -1
    )


def test_warp_previous_recovers_shift():
    prev, cur = _pattern(24, 32, 0.0), _pattern(24, 32, 1.5)  # content moved 1.5 px right
    motion = np.zeros((24, 32, 2))
    motion[..., 0] = -1.5  # previous position = current + motion
    warped, inb = warp_previous(prev, motion)
    assert not inb[:, :2].any() and inb[:, 2:].all()
    err = np.abs(warped - cur)[inb].max()
    assert err < 0.02  # bilinear on a smooth pattern
    assert np.abs(prev - cur)[inb].max() > 0.2


def _write_synthetic_sequence(path, sign: float):
    for t in range(3):
        img = _pattern(24, 32, 2.0 * t)
        ch = {c: img[..., i] for i, c in enumerate("RGB")}
        write_exr(path / f"ref_{t:04d}.exr", ch, half=False)
        feats = {**ch, "depth.Z": np.full((24, 32), 3.0), "motion.Y": np.zeros((24, 32))}
        feats["motion.X"] = np.full((24, 32), sign * -2.0 if t else 0.0)
        write_exr(path / f"frame_{t:04d}.exr", feats, half=False)


def test_warp_gain_detects_sign_errors(tmp_path):
    (tmp_path / "good").mkdir()
    (tmp_path / "bad").mkdir()
    _write_synthetic_sequence(tmp_path / "good", 1.0)
    _write_synthetic_sequence(tmp_path / "bad", -1.0)
    assert warp_gain_db(tmp_path / "good") > 15.0
    assert warp_gain_db(tmp_path / "bad") < 0.0


# ----------------------------------------------------------------- real renders


@needs_mitsuba
def test_projection_matches_mitsuba():
    import mitsuba as mi

    from rtdenoise.datagen.render import _AOVS, _aovs
    from rtdenoise.datagen.scene import build_scene, random_scene
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")
    cam = Camera((2.5, 1.6, 3.1), (0.1, 0.4, -0.2), (0.0, 1.0, 0.0), 47.0, 24, 18)
    m = np.array(
        mi.ScalarTransform4f().look_at(origin=cam.origin, target=cam.target, up=cam.up).matrix
    )
    np.testing.assert_allclose(m[:3, :3], cam.basis(), atol=1e-6)
    scene = build_scene(random_scene(3))
    a = _aovs(mi, scene, mi.load_dict({"type": "aov", "aovs": _AOVS}), cam)
    hit = np.linalg.norm(a["pp"], axis=-1) > 0
    assert hit.mean() > 0.5
    u, v, _ = project(a["pp"], cam)
    u0, v0 = pixel_centres(24, 18)
    assert np.abs(u - u0)[hit].max() < 2e-3 and np.abs(v - v0)[hit].max() < 2e-3


@needs_mitsuba
def test_render_sphere_conventions(tmp_path):
    from rtdenoise.datagen.render import render_sequence
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")
    desc = {
        "objects": [
            {
                "shape": "sphere",
                "center": [0.0, 0.0, 0.0],
                "radius": 1.0,
                "material": {"type": "conductor", "material": "Au"},
            }
        ],
        "lights": [],
        "environment": {"type": "constant", "radiance": [0.5, 0.5, 0.5]},
    }
    cams = [
        Camera((dx, 0.0, 5.0), (dx, 0.0, 0.0), (0.0, 1.0, 0.0), 40.0, 16, 16) for dx in (0, 0.1)
    ]
    cfg = RenderConfig(16, 16, 2, spp_ref=4, half=False)
    render_sequence(tmp_path, 0, cfg, variant="scalar_rgb", scene=desc, cameras=cams)
    f = read_exr(tmp_path / "frame_0001.exr")
    sph = f["depth.Z"] < 100
    assert 40 < sph.sum() < 120  # radius ~ 4.5 px
    assert f["normal.X"][8, 11] > 0.3 and f["normal.X"][8, 4] < -0.3  # x right
    assert f["normal.Y"][4, 8] > 0.3 and f["normal.Y"][11, 8] < -0.3  # y up
    assert f["normal.Z"][7, 7] > 0.9  # z towards the camera
    assert f["depth.Z"][7:9, 7:9].min() == pytest.approx(4.0, abs=0.05)
    assert (f["depth.Z"][~sph] == 1e4).all() and (f["albedo.R"][~sph] == 1).all()
    # camera moved +x by 0.1: the sphere was further right before: motion.X = f dx / z
    expected = cams[1].focal_px * 0.1 / f["depth.Z"][sph]
    np.testing.assert_allclose(f["motion.X"][sph], expected, rtol=1e-3)
    assert np.abs(f["motion.Y"]).max() < 1e-4 and np.abs(f["motion.X"][~sph]).max() < 1e-4
    gold = [f[f"albedo.{c}"][8, 8] for c in "RGB"]  # conductor albedo = F0 of gold
    assert gold[0] > 0.9 and gold[2] < 0.5


@needs_mitsuba
def test_cli_renders_tiny_sequence(tmp_path):
    from typer.testing import CliRunner

    from rtdenoise.cli.render import app

    runner = CliRunner()
    args = f"{tmp_path} -n 1 -f 3 --size 24x20 --spp-ref 64 --seed 5".split()
    r = runner.invoke(app, args)
    assert r.exit_code == 0, r.output
    seq = tmp_path / "seq_000"
    names = sorted(p.name for p in seq.iterdir())
    expected = [f"{k}_{t:04d}.exr" for k in ("frame", "ref") for t in range(3)] + ["meta.json"]
    assert names == sorted(expected)
    meta = json.loads((seq / "meta.json").read_text())
    assert meta["resolution"] == [24, 20] and meta["frame_count"] == 3
    assert meta["spp"]["ref"] == 64 and meta["scene_seed"] == derive_seed(5, 0)
    assert meta["job"] == {"base_seed": 5, "index": 0}
    assert meta["renderer"]["variant"] == "scalar_rgb" and meta["renderer"]["version"]
    assert len(meta["cameras"]) == 3
    assert {"origin", "target", "up", "fov"} <= set(meta["cameras"][0])
    assert set(meta["conventions"]) >= {"normal", "depth", "motion", "albedo"}
    with OpenEXR.File(str(seq / "frame_0002.exr"), separate_channels=True) as exr:
        chans = exr.channels()
        assert set(chans) == FRAME_CHANNELS
        assert {(c.pixels.dtype, c.pixels.shape) for c in chans.values()} == {
            (np.dtype(np.float16), (20, 24))
        }
    f, ref = read_exr(seq / "frame_0002.exr"), read_exr(seq / "ref_0002.exr")
    assert all(np.isfinite(a).all() for a in (*f.values(), *ref.values()))
    n = np.sqrt(f["normal.X"] ** 2 + f["normal.Y"] ** 2 + f["normal.Z"] ** 2)
    assert np.all((np.abs(n - 1) < 2e-3) | (n == 0)) and (n > 0).mean() > 0.5
    assert (f["depth.Z"] > 0).all() and 0 < np.abs(f["motion.X"]).max() < 10
    noisy = np.stack([f[c] for c in "RGB"], -1)
    clean = np.stack([ref[c] for c in "RGB"], -1)
    assert 5.0 < psnr(tonemap(noisy), tonemap(clean)) < 30.0
    assert not math.isclose(float(f["R"].sum()), float(f["colorB.R"].sum()))  # other seed
    # complete sequences are skipped; bad arguments give a usage error
    r = runner.invoke(app, args)
    assert r.exit_code == 0 and "skipping 1 complete" in r.output
    assert runner.invoke(app, [str(tmp_path), "--size", "24by20"]).exit_code == 2
    assert runner.invoke(app, [str(tmp_path), "--variant", "cuda_rgb"]).exit_code == 2


@needs_mitsuba
def test_cuda_variant_falls_back_in_order(monkeypatch):
    """No usable CUDA: cuda_ad_rgb falls to llvm_ad_rgb, and with no LLVM 19 to scalar_rgb,
    each fall named; the variant set is the one returned."""
    import mitsuba as mi

    from rtdenoise.datagen import variant

    probed = []

    def refuse(name, env=None, timeout=120.0):
        probed.append(name)
        return False, "no CUDA driver"

    monkeypatch.setattr(variant, "probe_variant", refuse)
    monkeypatch.setattr(variant, "find_libllvm19", lambda: None)
    warnings: list[str] = []
    assert variant.select_variant("cuda_ad_rgb", warn=warnings.append) == "scalar_rgb"
    assert probed == ["cuda_ad_rgb"]
    assert "cuda_ad_rgb failed (no CUDA driver)" in warnings[0]
    assert "llvm_ad_rgb needs LLVM 19" in warnings[1]
    assert mi.variant() == "scalar_rgb"
