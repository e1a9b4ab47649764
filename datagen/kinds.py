"""Scene kinds: named generators of random scene descriptions, chosen from the seed by weight.

`generate_scene(seed, kinds=None, exclude=())` picks one kind with `choose_kind` (its own
random stream, derived from the seed, weighted by `KINDS[name].weight` among the allowed
kinds), then draws that kind's description from `np.random.default_rng(seed)`; the same seed
and allowed set always give the same JSON. Every description has `seed`, `kind`, `objects`,
`lights`, `environment` and (all kinds but `legacy`) `camera`, a path spec (paths.py).

Kinds (`describe_kinds()` lists them):
- legacy: the original generator (objects on a ground plane, one orbit); weight 0, only when
  named: `scripts/make_test_sequences.sh` regenerates the committed sequences with it;
- objects: the same layout with every camera path and cuts;
- room: a closed room lit through 1-2 windows (a sky panel outside each, sun and sky beyond);
- box_hidden: a closed box lit only by emitters hidden on top of shelves, facing the ceiling;
- corridor: a long corridor with openings along one side, lamps on the ceiling sometimes;
- glass: dielectrics (smooth, rough, tinted, thin panes) under a small bright light: caustics;
- water: a pool with a wavy water surface (dielectric, IOR 1.333) over a tiled floor;
- thin: grilles of thin bars or tubes, foliage (hundreds of small leaves), wires;
- texture: high-frequency textures (text-like glyphs, fine stripes, fine checkers);
- lights: small bright emitters and emitting panels in view, over a glossy floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from .paths import draw_path
from .scene import CONDUCTORS, _material, _texture, random_scene
from .seeds import derive_seed
from .textures import HF_PATTERNS, PATTERNS


@dataclass(frozen=True)
class Kind:
    name: str
    weight: float
    generate: Callable[[int], dict]  # seed -> description (without `seed` and `kind`)
    summary: str
    ref_spp_scale: int = 1  # references at this many times --spp-ref (render.reference_spp)


INTERIOR_FOV = (55.0, 80.0)  # wider than outdoors: rooms are small


def _f(x) -> float:
    return round(float(x), 5)


def _v(xs) -> list[float]:
    return [_f(x) for x in xs]


def _col(rng: np.random.Generator, lo: float = 0.05, hi: float = 0.9) -> list[float]:
    return _v(rng.uniform(lo, hi, size=3))


def _hf_texture(rng: np.random.Generator) -> dict:
    return {
        "kind": "bitmap",
        "pattern": str(rng.choice(HF_PATTERNS)),
        "color0": _col(rng, 0.02, 0.3),
        "color1": _col(rng, 0.5, 0.95),
        "scale": float(rng.choice([1.0, 2.0, 3.0])),
        "seed": int(rng.integers(0, 2**31 - 1)),
        "size": 256,
    }


def _diffuse(rng: np.random.Generator, lo: float = 0.1, hi: float = 0.85, tex: float = 0.3):
    if rng.random() < tex:
        t = _texture(rng)
    else:
        t = {"kind": "rgb", "value": _col(rng, lo, hi)}
    return {"type": "diffuse", "reflectance": t}


def _glossy(rng: np.random.Generator) -> dict:
    if rng.random() < 0.5:
        return {"type": "roughconductor", "material": str(rng.choice(CONDUCTORS)),
                "alpha": _f(rng.uniform(0.03, 0.25))}  # fmt: skip
    return {"type": "roughplastic", "diffuse_reflectance": {"kind": "rgb", "value": _col(rng)},
            "alpha": _f(rng.uniform(0.02, 0.2))}  # fmt: skip


def _glass(rng: np.random.Generator) -> dict:
    kind = str(rng.choice(["dielectric", "roughdielectric"], p=[0.65, 0.35]))
    m: dict = {"type": kind, "int_ior": _f(rng.choice([1.33, 1.45, 1.5, 1.52, 1.6, 1.7]))}
    if kind == "roughdielectric":
        m["alpha"] = _f(math.exp(rng.uniform(math.log(0.02), math.log(0.3))))
    if rng.random() < 0.3:
        m["tint"] = _v(np.clip(rng.uniform(0.4, 1.0, 3), 0, 1))
    return m


def _sky(
    rng: np.random.Generator,
    sun_dir=None,
    scale: tuple[float, float] = (0.3, 1.5),
    sun_size: tuple[float, float] = (2.0, 6.0),
    sun_radiance: tuple[float, float] = (5.0, 40.0),
) -> dict:
    if sun_dir is None:
        el, az = rng.uniform(math.radians(10), math.radians(70)), rng.uniform(0, 2 * math.pi)
        sun_dir = [math.cos(el) * math.cos(az), math.sin(el), math.cos(el) * math.sin(az)]
    return {
        "type": "sky",
        "zenith": _col(rng, 0.05, 0.6),
        "horizon": _col(rng, 0.3, 1.0),
        "ground": _col(rng, 0.02, 0.2),
        "sun_dir": _v(sun_dir),
        "sun_radiance": _f(rng.uniform(*sun_radiance)),
        "sun_size_deg": _f(rng.uniform(*sun_size)),
        "scale": _f(rng.uniform(*scale)),
    }


def _sphere_light(center, radius: float, power: float, rng: np.random.Generator) -> dict:
    tint = np.clip(1.0 + rng.normal(0.0, 0.15, 3), 0.6, 1.4)
    return {"type": "sphere", "center": _v(center), "radius": _f(radius),
            "radiance": _v(power * tint)}  # fmt: skip


def _rect_light(position, target, size, radiance) -> dict:
    return {"type": "rectangle", "position": _v(position), "target": _v(target),
            "size": _v(size) if isinstance(size, (list, tuple)) else _f(size),
            "radiance": _v(radiance)}  # fmt: skip


def _ground(rng: np.random.Generator, hf: float = 0.0) -> dict:
    tex = _hf_texture(rng) if rng.random() < hf else _texture(rng)
    if tex["kind"] != "rgb":
        tex["scale"] = float(rng.choice([6.0, 10.0, 16.0]))
    return {"shape": "ground", "size": 12.0, "material": {"type": "diffuse", "reflectance": tex}}


def _place(rng, placed: list, r: float, lo, hi) -> tuple[float, float]:
    """A floor position (x, z) in [lo, hi] (2-D) not overlapping earlier ones (best effort)."""
    x = z = 0.0
    # A range narrower than the prop (a wide pool leaves little floor beside it) pins that
    # axis to the range's middle rather than asking numpy for an empty interval.
    (x_lo, x_hi), (z_lo, z_hi) = (
        (a + r, b - r) if b - a >= 2 * r else ((a + b) / 2,) * 2
        for a, b in zip(lo, hi, strict=True)
    )
    for _ in range(100):
        x, z = rng.uniform(x_lo, x_hi), rng.uniform(z_lo, z_hi)
        if all((x - px) ** 2 + (z - pz) ** 2 > (r + pr + 0.05) ** 2 for px, pz, pr in placed):
            break
    placed.append((float(x), float(z), r))
    return float(x), float(z)


def _prop(rng, placed: list, lo, hi, material: dict | None = None) -> dict:
    """A sphere, cube, cylinder or box standing on the floor at y = 0."""
    shape = str(rng.choice(["sphere", "cube", "cylinder", "box"]))
    size = float(rng.uniform(0.2, 0.5))
    x, z = _place(rng, placed, size, lo, hi)
    mat = material or _material(rng)
    if shape == "sphere":
        return {"shape": "sphere", "center": _v([x, size, z]), "radius": _f(size), "material": mat}
    if shape == "cube":
        return {"shape": "cube", "position": _v([x, size * 0.8, z]), "size": _f(size * 0.8),
                "rotation_y": _f(rng.uniform(0, 90)), "material": mat}  # fmt: skip
    if shape == "cylinder":
        return {"shape": "cylinder", "position": _v([x, 0.0, z]), "radius": _f(size * 0.6),
                "height": _f(rng.uniform(0.6, 2.5) * size), "material": mat}  # fmt: skip
    dims = rng.uniform(0.3, 1.0, 3) * size * 2
    return {"shape": "mesh", "material": mat, "mesh": {
        "kind": "box", "center": _v([x, dims[1] / 2, z]), "size": _v(dims),
        "rotation_y": _f(rng.uniform(0, 90))}}  # fmt: skip


def _opening(wall: str, h0: float, h1: float, y0: float, y1: float) -> dict:
    """A hole in a room wall: horizontal fraction [h0, h1], vertical fraction [y0, y1]."""
    vertical_u = wall in ("x-", "z+")  # meshes.room: these walls have u = +Y
    rect = [y0, h0, y1, h1] if vertical_u else [h0, y0, h1, y1]
    return {"wall": wall, "rect": _v(rect)}


_OUTWARD = {"x-": (-1, 0, 0), "x+": (1, 0, 0), "z-": (0, 0, -1), "z+": (0, 0, 1)}


def _wall_point(wall: str, size, h: float, y: float, out: float) -> np.ndarray:
    """World point on a room wall (floor centre at the origin) at horizontal fraction h,
    vertical fraction y, moved `out` outside."""
    sx, sy, sz = size
    n = np.asarray(_OUTWARD[wall], np.float64)
    if wall[0] == "x":
        p = np.array([n[0] * sx / 2, y * sy, -sz / 2 + h * sz])
    else:
        p = np.array([-sx / 2 + h * sx, y * sy, n[2] * sz / 2])
    return p + n * out


def _room_shell(rng, size, openings: list[dict], wall_color=None) -> list[dict]:
    """Floor, ceiling and walls of a room as three meshes (separate materials)."""
    center = [0.0, 0.0, 0.0]
    floor_tex = _texture(rng) if rng.random() < 0.7 else {"kind": "rgb", "value": _col(rng)}
    floor_mat = {"type": "diffuse", "reflectance": floor_tex}
    if rng.random() < 0.35:
        floor_mat = {"type": "roughplastic", "diffuse_reflectance": floor_tex,
                     "alpha": _f(rng.uniform(0.05, 0.3))}  # fmt: skip
    wall = wall_color or _col(rng, 0.4, 0.9)
    walls = {"type": "diffuse", "reflectance": {"kind": "rgb", "value": wall}}
    ceiling = {"type": "diffuse", "reflectance": {"kind": "rgb", "value": _col(rng, 0.6, 0.9)}}
    shell = []
    for names, mat in ((["floor"], floor_mat), (["ceiling"], ceiling),
                       (["x-", "x+", "z-", "z+"], walls)):  # fmt: skip
        ops = [o for o in openings if o["wall"] in names]
        mesh = {"kind": "room", "center": center, "size": _v(size), "walls": names,
                "openings": ops}  # fmt: skip
        shell.append({"shape": "mesh", "material": mat, "mesh": mesh})
    return shell


def _room_anchor(size, margin: float = 0.4, max_eye: float = 1.9) -> dict:
    sx, sy, sz = size
    lo = [-sx / 2 + margin, 0.6, -sz / 2 + margin]
    hi = [sx / 2 - margin, min(sy - margin, max_eye), sz / 2 - margin]
    return {
        "mode": "box",
        "origin_box": [_v(lo), _v(hi)],
        "target_box": [
            _v([-sx / 2 + 0.2, 0.3, -sz / 2 + 0.2]),
            _v([sx / 2 - 0.2, sy * 0.7, sz / 2 - 0.2]),
        ],  # fmt: skip
        "bounds": [
            _v([-sx / 2 + 0.25, 0.3, -sz / 2 + 0.25]),
            _v([sx / 2 - 0.25, sy - 0.25, sz / 2 - 0.25]),
        ],  # fmt: skip
    }


# ------------------------------------------------------------------------ generators


def gen_legacy(seed: int) -> dict:
    """The original generator, unchanged (its orbit comes from render.py)."""
    return random_scene(seed)


def gen_objects(seed: int) -> dict:
    """The original layout with a camera path from a stream of its own (the layout's draws
    stay those of `random_scene`)."""
    path_rng = np.random.default_rng(derive_seed(seed, 8))
    anchor = {"mode": "orbit", "target": [0.0, 0.5, 0.0], "target_jitter": 0.15,
              "radius": [2.8, 4.4], "height": [0.9, 2.4]}  # fmt: skip
    return {**random_scene(seed), "camera": draw_path(path_rng, anchor)}


def _seeded(gen: Callable[[np.random.Generator], dict]) -> Callable[[int], dict]:
    """A generator of `np.random.default_rng(seed)` as one of the seed."""
    return lambda seed: gen(np.random.default_rng(seed))


def gen_room(rng: np.random.Generator) -> dict:
    size = [rng.uniform(3.5, 6.0), rng.uniform(2.4, 3.2), rng.uniform(3.5, 6.0)]
    n_win = int(rng.integers(1, 3))
    walls = list(rng.choice(list(_OUTWARD), size=n_win, replace=False))
    openings, lights = [], []
    sun_wall = str(walls[0])
    n = np.asarray(_OUTWARD[sun_wall], np.float64)
    el = rng.uniform(math.radians(15), math.radians(50))
    side = rng.normal(0.0, 0.5)
    t = np.array([-n[2], 0.0, n[0]])
    sun = n * math.cos(el) + t * side * math.cos(el) + np.array([0, math.sin(el), 0])
    env = _sky(rng, sun / np.linalg.norm(sun), scale=(0.5, 1.5))
    for wall in walls:
        h0 = rng.uniform(0.15, 0.5)
        h1 = min(h0 + rng.uniform(0.2, 0.45), 0.9)
        y0 = rng.uniform(0.05, 0.35) if rng.random() < 0.3 else rng.uniform(0.3, 0.45)
        y1 = min(y0 + rng.uniform(0.3, 0.5), 0.92)
        openings.append(_opening(str(wall), h0, h1, y0, y1))
        if rng.random() < 0.7:  # a sky panel outside: light comes in through the opening
            hc, yc = (h0 + h1) / 2, (y0 + y1) / 2
            pos = _wall_point(str(wall), size, hc, yc, rng.uniform(0.3, 1.0))
            extent = size[0] if wall[0] == "z" else size[2]
            dims = [(h1 - h0) * extent * 1.6, (y1 - y0) * size[1] * 1.6]
            sky = np.asarray(env["horizon"]) * rng.uniform(1.0, 4.0)
            lights.append(_rect_light(pos, [0.0, size[1] * 0.3, 0.0], dims, sky))
    objects = _room_shell(rng, size, openings)
    placed: list = []
    lo, hi = (-size[0] / 2 + 0.2, -size[2] / 2 + 0.2), (size[0] / 2 - 0.2, size[2] / 2 - 0.2)
    for _ in range(int(rng.integers(2, 6))):
        objects.append(_prop(rng, placed, lo, hi))
    if rng.random() < 0.3:  # a small lamp in the room, seen directly
        x, z = _place(rng, placed, 0.1, lo, hi)
        centre = [x, rng.uniform(1.2, size[1] - 0.4), z]
        lights.append(_sphere_light(centre, rng.uniform(0.03, 0.08), rng.uniform(50, 400), rng))
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, _room_anchor(size), fov=INTERIOR_FOV)}  # fmt: skip


def gen_box_hidden(rng: np.random.Generator) -> dict:
    size = [rng.uniform(2.5, 4.0), rng.uniform(2.4, 3.2), rng.uniform(2.5, 4.0)]
    objects = _room_shell(rng, size, [])
    colors = [_col(rng, 0.5, 0.85) for _ in range(2)]
    colors[0][int(rng.integers(0, 3))] = 0.08  # two coloured side walls, Cornell-like
    colors[1][int(rng.integers(0, 3))] = 0.08
    for wall, c in zip(("x-", "x+"), colors, strict=True):
        mesh = {"kind": "room", "center": [0.0, 0.0, 0.0], "size": _v(size), "walls": [wall],
                "openings": []}  # fmt: skip
        mat = {"type": "diffuse", "reflectance": {"kind": "rgb", "value": c}}
        objects.append({"shape": "mesh", "mesh": mesh, "material": mat})
    objects[2]["mesh"]["walls"] = ["z-", "z+"]  # the coloured walls replace x- and x+
    shelf_y = rng.uniform(1.7, min(2.2, size[1] - 0.4))
    lights = []
    placed: list = []
    for wall in rng.choice(["x-", "x+", "z-", "z+"], size=int(rng.integers(1, 3)), replace=False):
        n = np.asarray(_OUTWARD[str(wall)], np.float64)
        depth = rng.uniform(0.25, 0.45)
        along = rng.uniform(0.8, 1.6)
        p = n * (np.array([size[0], 0, size[2]]) / 2 - depth / 2)
        p[1] = shelf_y - 0.04
        dims = np.where(np.abs(n) > 0, depth, along)
        dims[1] = 0.08
        objects.append({"shape": "mesh", "material": _diffuse(rng, 0.4, 0.8, 0.0),
                        "mesh": {"kind": "box", "center": _v(p), "size": _v(dims)}})  # fmt: skip
        top = p + np.array([0.0, 0.05, 0.0])
        radiance = np.clip(1.0 + rng.normal(0, 0.1, 3), 0.7, 1.3) * rng.uniform(10, 40)
        lights.append(
            _rect_light(
                top,
                top + np.array([0.0, 1.0, 0.0]),
                [float(dims[0]) * 0.9, float(dims[2]) * 0.9],
                radiance,
            )
        )
    lo, hi = (-size[0] / 2 + 0.6, -size[2] / 2 + 0.6), (size[0] / 2 - 0.6, size[2] / 2 - 0.6)
    for _ in range(int(rng.integers(2, 5))):
        objects.append(_prop(rng, placed, lo, hi))
    anchor = _room_anchor(size, margin=0.5, max_eye=shelf_y - 0.35)
    anchor["bounds"][1][1] = _f(shelf_y - 0.3)  # the emitters' faces stay above the eye
    return {"objects": objects, "lights": lights, "environment": {"type": "none"},
            "camera": draw_path(rng, anchor, fov=INTERIOR_FOV)}  # fmt: skip


def gen_corridor(rng: np.random.Generator) -> dict:
    size = [rng.uniform(1.8, 3.0), rng.uniform(2.5, 3.2), rng.uniform(8.0, 14.0)]
    n_open = int(rng.integers(3, 6))
    doors = rng.random() < 0.4
    openings = []
    for k in range(n_open):
        c = (k + 0.5) / n_open
        w = rng.uniform(0.25, 0.6) / n_open
        y0, y1 = (0.0, 0.75) if doors else (rng.uniform(0.3, 0.4), rng.uniform(0.75, 0.9))
        openings.append(_opening("x+", c - w, c + w, y0, y1))
    el = rng.uniform(math.radians(15), math.radians(45))
    sun = np.array([math.cos(el), math.sin(el), rng.normal(0, 0.6)])
    env = _sky(rng, sun / np.linalg.norm(sun), scale=(0.5, 1.5))
    objects = _room_shell(rng, size, openings)
    lights = []
    if rng.random() < 0.6:  # one tall sky panel outside all the openings
        pos = [size[0] / 2 + rng.uniform(0.5, 1.5), size[1] * 0.5, 0.0]
        sky = np.asarray(env["horizon"]) * rng.uniform(1.0, 3.0)
        lights.append(_rect_light(pos, [0.0, size[1] * 0.5, 0.0], [size[2], size[1] * 1.2], sky))
    if rng.random() < 0.5:  # ceiling lamps, seen directly
        for k in range(int(rng.integers(2, 5))):
            z = -size[2] / 2 + (k + 0.5) * size[2] / 4
            lights.append(_sphere_light([0.0, size[1] - 0.15, z], rng.uniform(0.04, 0.1),
                                        rng.uniform(30, 200), rng))  # fmt: skip
    placed: list = []
    lo, hi = (-size[0] / 2 + 0.1, -size[2] / 2 + 0.3), (size[0] / 2 - 0.1, size[2] / 2 - 0.3)
    for _ in range(int(rng.integers(2, 6))):
        objects.append(_prop(rng, placed, lo, hi))
    sx, sy, sz = size
    end = float(rng.choice([-1.0, 1.0]))
    anchor = {
        "mode": "box",
        "origin_box": [
            _v([-sx / 2 + 0.4, 1.0, end * (sz / 2 - 2.5)]),
            _v([sx / 2 - 0.4, 1.8, end * (sz / 2 - 0.5)]),
        ],  # fmt: skip
        "target_box": [
            _v([-sx / 2 + 0.3, 0.6, -end * sz / 2 + end * 1.0]),
            _v([sx / 2 - 0.3, 1.8, -end * sz / 4]),
        ],  # fmt: skip
        "bounds": [
            _v([-sx / 2 + 0.25, 0.3, -sz / 2 + 0.25]),
            _v([sx / 2 - 0.25, sy - 0.25, sz / 2 - 0.25]),
        ],  # fmt: skip
    }
    for box in (anchor["origin_box"], anchor["target_box"]):  # lo <= hi on every axis
        lo, hi = np.minimum(box[0], box[1]), np.maximum(box[0], box[1])
        box[0], box[1] = _v(lo), _v(hi)
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, anchor, fov=INTERIOR_FOV)}  # fmt: skip


def _orbit_anchor(rng, target=(0.0, 0.5, 0.0), radius=(2.6, 4.2), height=(0.8, 2.4)) -> dict:
    return {"mode": "orbit", "target": _v(target), "target_jitter": 0.15,
            "radius": list(radius), "height": list(height)}  # fmt: skip


def _small_bright_light(rng, near=(0.0, 0.0, 0.0), radius=(0.1, 0.3)) -> dict:
    """A small sphere light above the scene. Behind glass or water its caustics reach the
    camera only by BSDF sampling, so they converge as the light's solid angle: below a radius
    of ~0.1 even a 4096-spp reference keeps fireflies (docs/data.md)."""
    ang = rng.uniform(0, 2 * math.pi)
    dist = rng.uniform(0.5, 2.0)
    c = [near[0] + dist * math.cos(ang), rng.uniform(1.2, 3.0), near[2] + dist * math.sin(ang)]
    radius = rng.uniform(*radius)
    power = rng.uniform(2.0, 8.0) * c[1] ** 2 / radius**2
    return _sphere_light(c, radius, power, rng)


def gen_glass(rng: np.random.Generator) -> dict:
    objects = [_ground(rng, hf=0.2)]
    placed: list = []
    lo, hi = (-2.0, -2.0), (2.0, 2.0)
    for _ in range(int(rng.integers(2, 5))):
        obj = _prop(rng, placed, lo, hi, material=_glass(rng))
        if obj["shape"] == "cylinder":  # a capped cylinder is two shapes: not a closed solid
            obj = {
                "shape": "sphere",
                "center": [obj["position"][0], obj["radius"] * 1.4, obj["position"][2]],
                "radius": obj["radius"] * 1.4,
                "material": obj["material"],
            }
        objects.append(obj)
    if rng.random() < 0.6:  # a glass pane (thin box) standing upright
        x, z = _place(rng, placed, 0.5, lo, hi)
        mat = {"type": str(rng.choice(["dielectric", "thindielectric"])), "int_ior": 1.5}
        w, h = rng.uniform(0.6, 1.4), rng.uniform(0.5, 1.2)
        objects.append({"shape": "mesh", "material": mat, "mesh": {
            "kind": "box", "center": _v([x, h / 2, z]), "size": _v([w, h, 0.015]),
            "rotation_y": _f(rng.uniform(0, 180))}})  # fmt: skip
    for _ in range(int(rng.integers(1, 3))):  # diffuse things to see through the glass
        objects.append(_prop(rng, placed, lo, hi, material=_diffuse(rng, tex=0.6)))
    lights = [_small_bright_light(rng, radius=(0.15, 0.4)) for _ in range(int(rng.integers(1, 3)))]
    if rng.random() < 0.6:
        env = {"type": "constant", "radiance": _col(rng, 0.02, 0.2)}
    else:
        env = _sky(rng, scale=(0.2, 0.6), sun_size=(6.0, 12.0), sun_radiance=(1.0, 8.0))
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, _orbit_anchor(rng))}  # fmt: skip


def gen_water(rng: np.random.Generator) -> dict:
    px, pz, depth = rng.uniform(2.0, 3.5), rng.uniform(2.0, 3.5), rng.uniform(0.4, 0.8)
    tiles = {"kind": "checker" if rng.random() < 0.5 else "bitmap",
             "color0": _col(rng, 0.05, 0.4), "color1": _col(rng, 0.5, 0.95),
             "scale": float(rng.choice([8.0, 12.0, 20.0]))}  # fmt: skip
    if tiles["kind"] == "bitmap":
        tiles |= {"pattern": "grid", "seed": int(rng.integers(0, 2**31 - 1))}
    pool = {"kind": "room", "center": [0.0, -depth, 0.0], "size": _v([px, depth, pz]),
            "walls": ["floor", "x-", "x+", "z-", "z+"], "openings": []}  # fmt: skip
    objects = [
        {"shape": "mesh", "mesh": pool, "material": {"type": "diffuse", "reflectance": tiles}},
        {"shape": "mesh", "material": _diffuse(rng, 0.3, 0.8, tex=0.5),
         "mesh": {"kind": "deck", "size": 12.0, "y": 0.0,
                  "hole": _v([-px / 2, -pz / 2, px / 2, pz / 2])}},
    ]  # fmt: skip
    level = -rng.uniform(0.05, 0.2)
    waves = []
    for _ in range(int(rng.integers(2, 6))):
        k = rng.uniform(2.0, 12.0)
        a = rng.uniform(0, 2 * math.pi)
        waves.append(_v([rng.uniform(0.002, 0.02) * 6 / k, k * math.cos(a), k * math.sin(a),
                         rng.uniform(0, 2 * math.pi)]))  # fmt: skip
    water = {"type": "dielectric", "int_ior": 1.333}
    if rng.random() < 0.3:
        water = {"type": "roughdielectric", "int_ior": 1.333, "alpha": _f(rng.uniform(0.01, 0.08))}
    if rng.random() < 0.5:
        water["tint"] = _v(np.clip([rng.uniform(0.6, 0.9), rng.uniform(0.85, 1.0), 1.0], 0, 1))
    objects.append({"shape": "mesh", "material": water, "mesh": {
        "kind": "heightfield", "center": _v([0.0, level, 0.0]), "size": _v([px, pz]),
        "resolution": 64, "waves": waves}})  # fmt: skip
    placed: list = []
    for _ in range(int(rng.integers(1, 4))):  # things beside the pool
        side = rng.choice([-1.0, 1.0])
        x0 = side * (px / 2 + 0.3)
        objects.append(_prop(rng, placed, (min(x0, side * 2.8), -2.5), (max(x0, side * 2.8), 2.5)))
    # The pool floor is lit through the water only by BSDF-sampled paths (caustics): a wide,
    # dim sun and no small light keep its references convergent (docs/data.md).
    lights: list = []
    env = _sky(rng, scale=(0.5, 1.5), sun_size=(10.0, 20.0), sun_radiance=(1.0, 4.0))
    anchor = _orbit_anchor(rng, target=(0.0, -0.2, 0.0), radius=(2.2, 4.0), height=(0.8, 2.6))
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, anchor)}  # fmt: skip


def gen_thin(rng: np.random.Generator) -> dict:
    objects = [_ground(rng, hf=0.4)]
    back = _hf_texture(rng) if rng.random() < 0.5 else _texture(rng)
    objects.append({"shape": "mesh", "material": {"type": "diffuse", "reflectance": back},
                    "mesh": {"kind": "box", "center": [0.0, 1.5, -2.6], "size": [8.0, 3.0, 0.1],
                             "rotation_y": _f(rng.uniform(-30, 30))}})  # fmt: skip
    placed: list = []
    lo, hi = (-2.0, -2.0), (2.0, 2.0)
    for _ in range(int(rng.integers(1, 3))):
        x, z = _place(rng, placed, 0.6, lo, hi)
        w, h = rng.uniform(0.8, 2.0), rng.uniform(0.6, 1.6)
        spec = {"kind": "grille", "center": _v([x, h / 2 + 0.05, z]), "width": _f(w),
                "height": _f(h), "bars": int(rng.integers(8, 30)),
                "thickness": _f(rng.uniform(0.008, 0.04)), "rotation_y": _f(rng.uniform(0, 180)),
                "round": bool(rng.random() < 0.5), "cross": bool(rng.random() < 0.35)}  # fmt: skip
        mat = _glossy(rng) if rng.random() < 0.5 else _diffuse(rng, tex=0.0)
        objects.append({"shape": "mesh", "material": mat, "mesh": spec})
    for _ in range(int(rng.integers(1, 4))):
        x, z = _place(rng, placed, 0.5, lo, hi)
        r = rng.uniform(0.3, 0.7)
        spec = {"kind": "foliage", "seed": int(rng.integers(0, 2**31 - 1)),
                "center": _v([x, r + rng.uniform(0.0, 0.4), z]), "radius": _f(r),
                "leaves": int(rng.integers(120, 400)), "leaf_size": _f(rng.uniform(0.06, 0.16)),
                "stems": int(rng.integers(3, 8))}  # fmt: skip
        green = [rng.uniform(0.05, 0.3), rng.uniform(0.3, 0.7), rng.uniform(0.02, 0.25)]
        mat = {"type": "diffuse", "reflectance": {"kind": "rgb", "value": _v(green)}}
        if rng.random() < 0.3:
            mat = {"type": "roughplastic", "diffuse_reflectance": mat["reflectance"],
                   "alpha": _f(rng.uniform(0.1, 0.3))}  # fmt: skip
        objects.append({"shape": "mesh", "material": mat, "mesh": spec})
    if rng.random() < 0.6:
        segs = []
        for _ in range(int(rng.integers(3, 9))):
            a = rng.uniform(-3, 3, 3) * (1, 0, 1) + (0, rng.uniform(0.8, 2.8), 0)
            b = rng.uniform(-3, 3, 3) * (1, 0, 1) + (0, rng.uniform(0.8, 2.8), 0)
            segs.append([_v(a), _v(b)])
        objects.append({"shape": "mesh", "material": _diffuse(rng, 0.02, 0.3, 0.0),
                        "mesh": {"kind": "wires", "radius": _f(rng.uniform(0.004, 0.012)),
                                 "segments": segs}})  # fmt: skip
    lights = [
        _rect_light(
            [rng.uniform(-3, 3), rng.uniform(3, 5), rng.uniform(0, 3)],
            [0, 0, 0],
            rng.uniform(0.5, 1.2),
            [rng.uniform(20, 60)] * 3,
        )
    ]
    return {"objects": objects, "lights": lights, "environment": _sky(rng),
            "camera": draw_path(rng, _orbit_anchor(rng, radius=(2.2, 3.8)))}  # fmt: skip


def gen_texture(rng: np.random.Generator) -> dict:
    objects = [_ground(rng, hf=0.8)]
    placed: list = []
    lo, hi = (-2.2, -2.2), (2.2, 2.2)
    for _ in range(int(rng.integers(3, 6))):
        tex = _hf_texture(rng) if rng.random() < 0.7 else _texture(rng)
        mat = {"type": "diffuse", "reflectance": tex}
        if rng.random() < 0.3:
            mat = {"type": "roughplastic", "diffuse_reflectance": tex,
                   "alpha": _f(rng.uniform(0.05, 0.3))}  # fmt: skip
        objects.append(_prop(rng, placed, lo, hi, material=mat))
    for _ in range(int(rng.integers(1, 3))):  # upright panels: signs, posters
        x, z = _place(rng, placed, 0.6, lo, hi)
        size = rng.uniform(0.5, 1.0)
        objects.append(
            {
                "shape": "panel",
                "position": _v([x, size * 1.2, z]),
                "width": _f(size * 1.5),
                "height": _f(size * 1.2),
                "rotation_y": _f(rng.uniform(0, 180)),
                "material": {"type": "diffuse", "reflectance": _hf_texture(rng)},
            }
        )
    lights = [
        _rect_light(
            [rng.uniform(-3, 3), rng.uniform(3, 5), rng.uniform(-3, 3)],
            [0, 0, 0],
            rng.uniform(0.5, 1.5),
            [rng.uniform(10, 40)] * 3,
        )
    ]
    env = _sky(rng) if rng.random() < 0.6 else {"type": "constant", "radiance": _col(rng, 0.1, 0.5)}
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, _orbit_anchor(rng))}  # fmt: skip


def gen_lights(rng: np.random.Generator) -> dict:
    floor = _glossy(rng)
    objects = [{"shape": "ground", "size": 12.0, "material": floor}]
    placed: list = []
    lo, hi = (-2.0, -2.0), (2.0, 2.0)
    for _ in range(int(rng.integers(2, 5))):
        objects.append(_prop(rng, placed, lo, hi))
    lights = []
    for _ in range(int(rng.integers(3, 9))):  # small bright emitters inside the view
        x, z = _place(rng, placed, 0.1, lo, hi)
        r = rng.uniform(0.015, 0.08)
        lights.append(_sphere_light([x, rng.uniform(0.1, 1.8), z], r,
                                    rng.uniform(0.5, 3.0) / r, rng))  # fmt: skip
    for _ in range(int(rng.integers(0, 3))):  # emitting panels facing the middle
        x, z = _place(rng, placed, 0.3, lo, hi)
        pos = [x, rng.uniform(0.4, 1.6), z]
        lights.append(_rect_light(pos, [0.0, pos[1], 0.0], [rng.uniform(0.1, 0.5),
                                  rng.uniform(0.1, 0.8)], rng.uniform(2, 20, 3)))  # fmt: skip
    env = {"type": "constant", "radiance": _col(rng, 0.0, 0.05)}
    return {"objects": objects, "lights": lights, "environment": env,
            "camera": draw_path(rng, _orbit_anchor(rng, target=(0.0, 0.6, 0.0)))}  # fmt: skip


KINDS: dict[str, Kind] = {
    k.name: k
    for k in (
        Kind("legacy", 0.0, gen_legacy, "the original generator, one orbit (only when named)"),
        Kind("objects", 1.5, gen_objects, "objects on a ground plane, every camera path"),
        Kind("room", 2.0, _seeded(gen_room), "closed room lit through 1-2 windows"),
        Kind(
            "box_hidden",
            1.5,
            _seeded(gen_box_hidden),
            "closed box lit by hidden emitters on shelves",
            4,  # indirect light only: 256 spp is 33 dB from the truth, 1024 spp 38 dB
        ),
        Kind(
            "corridor",
            1.0,
            _seeded(gen_corridor),
            "long corridor, openings along one side",
            4,  # 256 spp: 34.5 dB from the truth, 1024 spp: 39.5 dB
        ),
        Kind("glass", 1.5, _seeded(gen_glass), "dielectrics under a small bright light (caustics)"),
        Kind("water", 1.0, _seeded(gen_water), "pool with a wavy water surface"),
        Kind("thin", 1.5, _seeded(gen_thin), "grilles, foliage, wires"),
        Kind("texture", 1.0, _seeded(gen_texture), "high-frequency textures (text, fine patterns)"),
        Kind("lights", 1.0, _seeded(gen_lights), "small bright emitters and panels seen directly"),
    )
}


def check_kinds(names: Iterable[str], option: str = "--kinds") -> list[str]:
    """The names, each checked against KINDS (ValueError naming `option` otherwise)."""
    out = []
    for name in names:
        if name not in KINDS:
            raise ValueError(f"{option}: unknown scene kind {name!r}; known: {', '.join(KINDS)}")
        out.append(name)
    return out


def allowed_kinds(kinds: Iterable[str] | None = None, exclude: Iterable[str] = ()) -> list[str]:
    """Kinds a job may draw: `kinds` (default: every kind with weight > 0) minus `exclude`."""
    exclude = set(check_kinds(exclude, "--exclude-kinds"))
    base = check_kinds(kinds) if kinds else [n for n, k in KINDS.items() if k.weight > 0]
    out = [n for n in base if n not in exclude]
    if not out:
        raise ValueError("--kinds / --exclude-kinds leave no scene kind to render")
    return out


def choose_kind(seed: int, allowed: list[str]) -> str:
    """The kind of scene `seed` among `allowed` (weighted; weight-0 kinds count as 1 when
    they are named, so `--kinds legacy` works)."""
    if len(allowed) == 1:
        return allowed[0]
    w = np.asarray([KINDS[n].weight or 1.0 for n in allowed], np.float64)
    rng = np.random.default_rng(derive_seed(seed, 7))
    return str(rng.choice(allowed, p=w / w.sum()))


def generate_scene(
    seed: int, kinds: Iterable[str] | None = None, exclude: Iterable[str] = ()
) -> dict:
    """A scene description of a kind drawn from `seed` (see the module docstring)."""
    kind = choose_kind(seed, allowed_kinds(kinds, exclude))
    return {"seed": int(seed), "kind": kind, **KINDS[kind].generate(seed)}


def describe_kinds() -> str:
    """One line per kind: name, weight, summary."""
    return "\n".join(f"{k.name:11s} weight {k.weight:3.1f}  {k.summary}" for k in KINDS.values())


__all__ = [
    "KINDS",
    "PATTERNS",
    "allowed_kinds",
    "check_kinds",
    "choose_kind",
    "describe_kinds",
    "generate_scene",
]
