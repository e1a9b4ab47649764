"""Scene kinds, camera paths, meshes and shards of the data engine (rtdenoise.datagen).

The description, path and mesh tests are numpy only; the render tests (each kind renders
finite buffers, cuts are recorded, the new paths' motion vectors pass the warp check) skip
without mitsuba, like tests/test_render.py.
"""

from __future__ import annotations

import importlib.util
import json
import math

import numpy as np
import pytest

from rtdenoise.datagen.kinds import KINDS, allowed_kinds, choose_kind, generate_scene
from rtdenoise.datagen.meshes import box, heightfield, mesh_arrays, room, wall_with_holes
from rtdenoise.datagen.paths import cameras_from_spec, cut_frames, draw_path
from rtdenoise.datagen.scene import random_scene
from rtdenoise.datagen.shards import parse_shard, release, shard_indices, try_lock
from rtdenoise.datagen.validate import warp_report
from rtdenoise.runtime.sequences.exr import read_exr, write_exr

HAS_MITSUBA = importlib.util.find_spec("mitsuba") is not None
needs_mitsuba = pytest.mark.skipif(not HAS_MITSUBA, reason="mitsuba not installed ([data] extra)")
NEW_KINDS = [k for k in KINDS if k != "legacy"]

# ----------------------------------------------------------------- descriptions


@pytest.mark.parametrize("kind", list(KINDS))
def test_descriptions_are_deterministic_json(kind):
    a, b = generate_scene(11, [kind]), generate_scene(11, [kind])
    assert a == b and a["kind"] == kind and a["seed"] == 11
    assert json.loads(json.dumps(a)) == a  # plain JSON, nothing numpy
    assert generate_scene(12, [kind]) != a
    assert {"objects", "lights", "environment"} <= set(a)
    assert ("camera" in a) == (kind != "legacy")


@pytest.mark.parametrize("kind", NEW_KINDS)
def test_every_seed_gives_a_scene(kind):
    # a wide pool once left less floor beside it than a prop needs: 11 % of water seeds
    # raised numpy's "high - low < 0" (seeds 9, 41, 42, ...) and stopped a render job
    for seed in range(200):
        desc = generate_scene(seed, [kind])
        assert desc["kind"] == kind and desc["objects"]


def test_legacy_kind_is_the_original_generator():
    # scripts/make_test_sequences.sh regenerates the committed sequences with --kinds legacy
    for seed in (0, 5, 123):
        desc = generate_scene(seed, ["legacy"])
        assert desc.pop("kind") == "legacy" and desc == random_scene(seed)


def test_kind_choice_respects_restrictions_and_weights():
    drawn = [choose_kind(s, allowed_kinds()) for s in range(400)]
    assert set(drawn) == set(NEW_KINDS)  # every weighted kind appears, legacy never
    counts = {k: drawn.count(k) for k in NEW_KINDS}
    assert counts["room"] > counts["corridor"]  # weight 2.0 against 1.0
    only = allowed_kinds(["glass", "water"])
    assert {choose_kind(s, only) for s in range(50)} == {"glass", "water"}
    held_out = allowed_kinds(None, ["corridor", "water"])
    assert not {choose_kind(s, held_out) for s in range(300)} & {"corridor", "water"}
    desc = generate_scene(7, None, ["corridor", "water"])
    assert desc["kind"] not in ("corridor", "water")
    with pytest.raises(ValueError, match="--kinds: unknown scene kind 'castle'"):
        allowed_kinds(["castle"])
    with pytest.raises(ValueError, match="--exclude-kinds: unknown"):
        allowed_kinds(None, ["glas"])
    with pytest.raises(ValueError, match="no scene kind"):
        allowed_kinds(["glass"], ["glass"])


def test_kinds_hold_what_they_promise():
    def materials(d):
        return {o["material"]["type"] for o in d["objects"]}

    def meshes(d):
        return {o["mesh"]["kind"] for o in d["objects"] if o["shape"] == "mesh"}

    for s in range(5):
        assert materials(generate_scene(s, ["glass"])) & {"dielectric", "roughdielectric"}
        water = generate_scene(s, ["water"])
        assert "heightfield" in meshes(water)
        assert {"grille", "foliage"} & meshes(generate_scene(s, ["thin"]))
        box_hidden = generate_scene(s, ["box_hidden"])
        assert box_hidden["environment"] == {"type": "none"}  # lit by the hidden emitters only
        eye_max = box_hidden["camera"]["bounds"][1][1]
        assert all(lt["position"][1] > eye_max for lt in box_hidden["lights"])
        room_desc = generate_scene(s, ["room"])
        walls = [o for o in room_desc["objects"] if o["shape"] == "mesh"
                 and o["mesh"]["kind"] == "room" and "x-" in o["mesh"]["walls"]]  # fmt: skip
        assert walls and walls[0]["mesh"]["openings"]  # light comes through an opening
        lights = generate_scene(s, ["lights"])["lights"]
        assert len(lights) >= 3 and min(lt.get("radius", 1.0) for lt in lights) < 0.1
    patterns = {
        o["material"]["reflectance"].get("pattern")
        for s in range(5)
        for o in generate_scene(s, ["texture"])["objects"]
        if "reflectance" in o["material"]
    }
    assert patterns & {"text", "fine_stripes", "fine_checker", "fine_noise"}


def test_reference_spp_per_kind():
    from rtdenoise.datagen.render import reference_spp

    assert reference_spp(256, "room") == 256 and reference_spp(256, None) == 256
    assert reference_spp(256, "box_hidden") == 1024 == reference_spp(256, "corridor")
    assert reference_spp(4096, "box_hidden") == 4096  # the validation set's count stays
    assert reference_spp(2048, "corridor") == 4096 and reference_spp(8192, "corridor") == 8192


# ----------------------------------------------------------------- camera paths


def _shot(path, **rates):
    return {"path": path, "origin": [0.0, 1.0, 4.0], "target": [0.0, 0.5, 0.0], "fov": 50.0,
            **rates}  # fmt: skip


def test_camera_paths_move_as_named():
    def poses(shot, n=5):
        cams, cuts = cameras_from_spec({"shots": [shot]}, n, 16, 16)
        assert cuts == []
        return np.array([c.origin for c in cams]), np.array([c.target for c in cams])

    o, t = poses(_shot("still"))
    assert np.ptp(o, 0).max() == 0 and np.ptp(t, 0).max() == 0
    o, t = poses(_shot("pan", yaw_rate=2.0, pitch_rate=0.0))
    assert np.ptp(o, 0).max() == 0 and np.ptp(t, 0).max() > 0.1
    d = t - o
    yaw = np.degrees(np.unwrap(np.arctan2(d[:, 0], d[:, 2])))
    np.testing.assert_allclose(np.diff(yaw), 2.0, atol=1e-6)
    o, t = poses(_shot("dolly", speed=0.2, min_distance=1.0))
    dist = np.linalg.norm(t - o, axis=1)
    np.testing.assert_allclose(np.diff(dist), -0.2, atol=1e-9)
    assert np.ptp(t, 0).max() == 0
    o, t = poses(_shot("orbit", omega=3.0, radius_rate=0.0))
    np.testing.assert_allclose(np.linalg.norm(o - t, axis=1), np.linalg.norm(o[0] - t[0]))
    assert np.ptp(t, 0).max() == 0 and np.ptp(o[:, 1]) == 0
    o, t = poses(_shot("fast", velocity=[0.3, 0.0, 0.0], yaw_rate=8.0))
    np.testing.assert_allclose(np.diff(o[:, 0]), 0.3)


def test_cuts_and_bounds():
    spec = {"shots": [_shot("still"), _shot("orbit", omega=2.0, radius_rate=0.0)],
            "cut_fractions": [0.5]}  # fmt: skip
    assert cut_frames(spec, 8) == [4] and cut_frames(spec, 1) == [] and cut_frames(spec, 2) == [1]
    cams, cuts = cameras_from_spec(spec, 8, 16, 16)
    assert cuts == [4] and cams[3].origin == cams[0].origin and cams[4].origin == cams[0].origin
    assert cams[5].origin != cams[4].origin  # the second shot moves from its own start
    spec = {"shots": [_shot("fast", velocity=[1.0, 0.0, 0.0], yaw_rate=0.0)],
            "bounds": [[-1.0, 0.0, -5.0], [1.0, 3.0, 5.0]]}  # fmt: skip
    cams, _ = cameras_from_spec(spec, 6, 16, 16)
    assert max(c.origin[0] for c in cams) == 1.0  # clamped to the room
    rng = np.random.default_rng(0)
    anchor = {"mode": "orbit", "target": [0, 0.5, 0], "radius": [3, 4], "height": [1, 2]}
    specs = [draw_path(rng, anchor) for _ in range(200)]
    n_cut = sum(len(s["shots"]) == 2 for s in specs)
    assert 20 < n_cut < 70  # CUT_PROBABILITY = 0.2
    assert {sh["path"] for s in specs for sh in s["shots"]} == {
        "still", "pan", "dolly", "orbit", "fast"
    }  # fmt: skip


# ----------------------------------------------------------------- meshes


def _geometric_normals(m):
    p = m.positions
    e = np.cross(p[m.faces[:, 1]] - p[m.faces[:, 0]], p[m.faces[:, 2]] - p[m.faces[:, 0]])
    return e, 0.5 * np.linalg.norm(e, axis=1)


def test_meshes_are_wound_like_their_normals():
    b = box([1.0, 2.0, 3.0], [2.0, 1.0, 0.5], rotation_y=30.0)
    e, area = _geometric_normals(b)
    centre = b.positions[b.faces].mean(1) - np.array([1.0, 2.0, 3.0])
    assert (np.sum(e * centre, 1) > 0).all()  # outward
    assert area.sum() == pytest.approx(2 * (2 * 1 + 2 * 0.5 + 1 * 0.5))
    r = room({"center": [0, 0, 0], "size": [4.0, 3.0, 5.0]})
    e, _ = _geometric_normals(r)
    centre = r.positions[r.faces].mean(1) - np.array([0, 1.5, 0])
    assert (np.sum(e * centre, 1) < 0).all()  # inward
    h = heightfield({"center": [0, 0, 0], "size": [2, 2], "resolution": 8,
                     "waves": [[0.05, 3.0, 1.0, 0.2]]})  # fmt: skip
    e, _ = _geometric_normals(h)
    assert (e[:, 1] > 0).all() and (h.normals[:, 1] > 0).all()
    wall = wall_with_holes([0, 0, 0], [4, 0, 0], [0, 2, 0], [[0.25, 0.25, 0.5, 0.75]])
    assert _geometric_normals(wall)[1].sum() == pytest.approx(8.0 - 1.0 * 1.0)
    for s in range(3):
        for o in generate_scene(s, ["thin"])["objects"]:
            if o["shape"] == "mesh":
                m = mesh_arrays(o["mesh"])
                assert np.isfinite(m.positions).all() and m.faces.max() < len(m.positions)
                np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-6)


# ----------------------------------------------------------------- shards and locks


def test_shards_partition_the_range():
    assert parse_shard("1/3") == (1, 3)
    for bad in ("3/3", "1", "a/b", "0/0"):
        with pytest.raises(ValueError, match="--shard"):
            parse_shard(bad)
    parts = [shard_indices(range(10, 30), (i, 4)) for i in range(4)]
    assert sorted(sum(parts, [])) == list(range(10, 30))
    assert not set(parts[0]) & set(parts[1])


def test_locks_exclude_live_processes_and_take_over_dead_ones(tmp_path):
    seq = tmp_path / "seq_000"
    lock = try_lock(seq)
    assert lock is not None and try_lock(seq) is None  # held by a live process (this one)
    release(lock)
    assert not lock.exists()
    import socket
    import subprocess
    import sys

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    (seq / ".lock").write_text(json.dumps({"host": socket.gethostname(), "pid": int(dead.stdout)}))
    lock = try_lock(seq)
    assert lock is not None  # its owner is gone: taken over
    release(lock)
    (seq / ".lock").write_text(json.dumps({"host": "another-host", "pid": 1}))
    assert try_lock(seq) is None  # another host's lock is left alone


# ----------------------------------------------------------------- warp check and cuts


def test_warp_report_skips_cut_frames(tmp_path):
    h, w = 24, 32
    y, x = np.mgrid[0:h, 0:w] + 0.5
    for t in range(4):
        img = np.stack([1 + np.sin((x - 2.0 * t) / 3.0), 0.5 + 0 * x, 0.3 + 0 * x], -1)
        if t >= 2:
            img = img[:, ::-1] * 3.0  # a cut: another view
        write_exr(tmp_path / f"ref_{t:04d}.exr", {c: img[..., i] for i, c in enumerate("RGB")})
        mx = np.full((h, w), -2.0 if t not in (0, 2) else 0.0)
        feats = {"depth.Z": np.full((h, w), 3.0), "motion.X": mx, "motion.Y": np.zeros((h, w))}
        write_exr(tmp_path / f"frame_{t:04d}.exr", feats)
    (tmp_path / "meta.json").write_text(json.dumps({"cuts": [2]}))
    assert [r.frame for r in warp_report(tmp_path)] == [1, 3]


# ----------------------------------------------------------------- renders


def _select():
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")


@needs_mitsuba
@pytest.mark.parametrize("kind", NEW_KINDS)
def test_every_kind_renders_finite_buffers(tmp_path, kind):
    from rtdenoise.datagen.render import RenderConfig, render_sequence

    _select()
    cfg = RenderConfig(16, 16, 2, spp_ref=8, half=True, kinds=(kind,))
    meta = render_sequence(tmp_path, 3, cfg, variant="scalar_rgb")
    assert meta["kind"] == kind and meta["scene"]["kind"] == kind
    scale = 4 if kind in ("box_hidden", "corridor") else 1  # slow-converging kinds: more spp
    assert 8 * scale <= meta["spp"]["ref"] < 8 * scale + 8
    for t in range(2):
        f, ref = read_exr(tmp_path / f"frame_{t:04d}.exr"), read_exr(tmp_path / f"ref_{t:04d}.exr")
        assert all(np.isfinite(a).all() for a in (*f.values(), *ref.values()))
        clean = np.stack([ref[c] for c in "RGB"])
        assert clean.max() > 0.0 and clean.min() >= 0.0
        assert 0.0 <= f["albedo.R"].min() and f["albedo.G"].max() <= 1.0
    assert not (tmp_path / "partial.json").exists()


def _objects_with(shots, cut_fractions=()):
    """random_scene(3) on a checkered ground under a constant sky (texture everywhere below the
    horizon, so that a warp has something to align), with the given shots."""
    desc = random_scene(3)
    checker = {"kind": "checker", "color0": [0.1, 0.1, 0.1], "color1": [0.8, 0.7, 0.5],
               "scale": 12.0}  # fmt: skip
    desc["objects"][0]["material"] = {"type": "diffuse", "reflectance": checker}
    return {**desc, "kind": "objects",
            "camera": {"shots": shots, "cut_fractions": list(cut_fractions)}}  # fmt: skip


@needs_mitsuba
def test_a_cut_is_recorded_and_its_motion_is_zero(tmp_path):
    from rtdenoise.datagen.render import RenderConfig, render_sequence

    _select()
    shots = [_shot("orbit", omega=3.0, radius_rate=0.0),
             {**_shot("pan", yaw_rate=2.0), "origin": [3.0, 1.5, -2.0]}]  # fmt: skip
    cfg = RenderConfig(24, 24, 4, spp_ref=16, half=False)
    meta = render_sequence(tmp_path, 0, cfg, variant="scalar_rgb",
                           scene=_objects_with(shots, [0.5]))  # fmt: skip
    assert meta["cuts"] == [2]
    assert [c["reset"] for c in meta["cameras"]] == [True, False, True, False]
    on_disk = json.loads((tmp_path / "meta.json").read_text())
    assert on_disk["cuts"] == [2] and on_disk["cameras"][2]["reset"] is True
    motion = {t: read_exr(tmp_path / f"frame_{t:04d}.exr") for t in range(4)}
    for t in (0, 2):  # no previous frame: motion 0 (contract: reset = 1 there)
        assert not np.abs(motion[t]["motion.X"]).any() and not np.abs(motion[t]["motion.Y"]).any()
    for t in (1, 3):
        assert np.abs(motion[t]["motion.X"]).max() > 0.3
    assert [r.frame for r in warp_report(tmp_path)] == [1, 3]


@needs_mitsuba
@pytest.mark.parametrize(
    "shot",
    [
        _shot("pan", yaw_rate=3.0, pitch_rate=0.5),
        _shot("dolly", speed=0.3, min_distance=1.0),
        _shot("orbit", omega=4.0, radius_rate=0.1),
        _shot("fast", velocity=[0.35, 0.05, -0.1], yaw_rate=6.0),
    ],
    ids=lambda s: s["path"],
)
def test_new_paths_motion_vectors_warp_references(tmp_path, shot):
    from rtdenoise.datagen.render import RenderConfig, render_sequence
    from rtdenoise.runtime.sequences.exr import read_exr as read

    _select()
    shot = {**shot, "origin": [0.0, 2.6, 3.6]}  # looking down: mostly checkered ground in view
    cfg = RenderConfig(40, 40, 3, spp_ref=128, half=False)
    render_sequence(tmp_path, 0, cfg, variant="scalar_rgb", scene=_objects_with([shot]))
    report = warp_report(tmp_path)
    assert len(report) == 2 and all(r.valid_fraction > 0.2 for r in report)
    assert all(r.gain_db > 3.0 for r in report), report
    f = read(tmp_path / "frame_0002.exr")
    assert math.hypot(float(np.abs(f["motion.X"]).max()), float(np.abs(f["motion.Y"]).max())) > 1
    # the same motion with its sign flipped warps worse than no warp at all
    for t in (1, 2):
        p = tmp_path / f"frame_{t:04d}.exr"
        ch = read(p)
        write_exr(p, {**ch, "motion.X": -ch["motion.X"], "motion.Y": -ch["motion.Y"]}, half=False)
    flipped = warp_report(tmp_path)
    assert all(f.gain_db < r.gain_db - 3.0 for f, r in zip(flipped, report, strict=True))


@needs_mitsuba
def test_cli_kinds_shards_and_list(tmp_path):
    from typer.testing import CliRunner

    from rtdenoise.cli.render import app

    runner = CliRunner()
    r = runner.invoke(app, ["--list-kinds"])
    assert r.exit_code == 0 and all(k in r.output for k in KINDS)
    args = f"{tmp_path} -n 4 -f 2 --size 16x16 --spp-ref 4 --seed 2 --kinds texture,lights"
    r = runner.invoke(app, [*args.split(), "--shard", "1/2"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq_001", "seq_003"]
    kinds = {json.loads((p / "meta.json").read_text())["kind"] for p in tmp_path.iterdir()}
    assert kinds <= {"texture", "lights"}
    assert not any((p / ".lock").exists() for p in tmp_path.iterdir())
    r = runner.invoke(app, [*args.split(), "--shard", "0/2"])
    assert r.exit_code == 0 and len(list(tmp_path.iterdir())) == 4
    r = runner.invoke(app, [*args.split(), "--exclude-kinds", "texture,lights"])
    assert r.exit_code == 2 and "no scene kind" in r.output
    r = runner.invoke(app, [*args.split(), "--kinds", "castle"])
    assert r.exit_code == 2 and "castle" in r.output
    r = runner.invoke(app, [*args.split(), "--shard", "2/2"])
    assert r.exit_code == 2 and "--shard" in r.output


@needs_mitsuba
def test_unusable_shots_are_drawn_again(tmp_path):
    import mitsuba as mi

    from rtdenoise.datagen.camera import Camera
    from rtdenoise.datagen.render import _AOVS, RenderConfig, render_sequence, shot_problem
    from rtdenoise.datagen.scene import build_scene
    from rtdenoise.datagen.seeds import derive_seed

    _select()
    # sequence 18 of the v2 training job: its first draw puts the camera inside a prop
    cfg = RenderConfig(16, 16, 2, spp_ref=4, exclude_kinds=("corridor", "water"))
    meta = render_sequence(tmp_path, derive_seed(10000, 18), cfg, variant="scalar_rgb")
    assert meta["redraws"] and "black" in meta["redraws"][0]["why"]
    assert meta["scene"]["seed"] != meta["scene_seed"] and meta["exposure"] < 1e3
    assert meta == json.loads((tmp_path / "meta.json").read_text())
    grey = {"type": "diffuse", "reflectance": {"kind": "rgb", "value": [0.5] * 3}}
    ball = {"shape": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.15, "material": grey}
    env = {"type": "constant", "radiance": [1.0] * 3}
    scene = build_scene({"objects": [ball], "lights": [], "environment": env})
    aov = mi.load_dict({"type": "aov", "aovs": _AOVS})
    inside = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), 50.0, 16, 16)
    outside = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 50.0, 16, 16)
    lit = np.ones((16, 16, 3))
    assert "nearer than" in shot_problem(mi, scene, aov, [outside, inside], lit)
    assert shot_problem(mi, scene, aov, [outside], lit) is None
    assert "black" in shot_problem(mi, scene, aov, [outside], 0 * lit)
