"""Random scenes from an integer seed: a JSON description, then a Mitsuba 3 scene.

`random_scene(seed)` draws a plain, JSON-serialisable description (numpy only):
a textured ground plane, 3-6 objects (spheres, cubes, capped cylinders, tori,
two-sided panels) with diffuse / plastic / roughplastic / conductor /
roughconductor materials (checkerboard or numpy-generated bitmap textures),
1-2 area lights (rectangles or spheres) and an environment (constant or a
numpy sky map). `build_scene(desc)` turns it into a loaded `mi.Scene`
(mitsuba is imported there, with the variant already set by the caller).
"""

from __future__ import annotations

import math

import numpy as np

from .meshes import Mesh, mesh_arrays
from .textures import PATTERNS, pattern_texture, sky_envmap

CONDUCTORS = ("Au", "Cu", "Al", "Ag", "Cr", "W", "Ni_palik", "CuO")
DIELECTRICS = ("dielectric", "roughdielectric", "thindielectric")


SHAPES = ("ground", "sphere", "cube", "cylinder", "torus", "panel", "mesh")


def _color(rng: np.random.Generator, lo: float = 0.05, hi: float = 0.9) -> list[float]:
    return [round(float(x), 4) for x in rng.uniform(lo, hi, size=3)]


def _texture(rng: np.random.Generator) -> dict:
    kind = rng.choice(["rgb", "checker", "bitmap"], p=[0.4, 0.25, 0.35])
    if kind == "rgb":
        return {"kind": "rgb", "value": _color(rng)}
    tex = {
        "kind": str(kind),
        "color0": _color(rng, 0.02, 0.5),
        "color1": _color(rng, 0.3, 0.95),
        "scale": float(rng.choice([1.0, 2.0, 3.0, 4.0])),
    }
    if kind == "bitmap":
        tex["pattern"] = str(rng.choice(PATTERNS))
        tex["seed"] = int(rng.integers(0, 2**31 - 1))
    return tex


def _material(rng: np.random.Generator) -> dict:
    kind = str(
        rng.choice(
            ["diffuse", "plastic", "roughplastic", "conductor", "roughconductor"],
            p=[0.35, 0.1, 0.15, 0.1, 0.3],
        )
    )
    if kind == "diffuse":
        return {"type": kind, "reflectance": _texture(rng)}
    if kind in ("plastic", "roughplastic"):
        m = {"type": kind, "diffuse_reflectance": _texture(rng)}
        if kind == "roughplastic":
            m["alpha"] = round(float(rng.uniform(0.05, 0.4)), 4)
        return m
    m = {"type": kind, "material": str(rng.choice(CONDUCTORS))}
    if kind == "roughconductor":
        # log-uniform: near-smooth (0.01) to rough (0.5)
        m["alpha"] = round(float(math.exp(rng.uniform(math.log(0.01), math.log(0.5)))), 4)
    return m


def _place(rng: np.random.Generator, placed: list[tuple[float, float, float]], r: float):
    """A ground position (x, z) in a disk of radius 2.2 not overlapping earlier objects."""
    for _ in range(100):
        x, z = rng.uniform(-2.2, 2.2, size=2)
        if x * x + z * z > 2.2**2:
            continue
        if all((x - px) ** 2 + (z - pz) ** 2 > (r + pr + 0.05) ** 2 for px, pz, pr in placed):
            placed.append((float(x), float(z), r))
            return float(x), float(z)
    placed.append((float(x), float(z), r))
    return float(x), float(z)


def random_scene(seed: int) -> dict:
    """A random scene description (JSON-serialisable) from an integer seed."""
    rng = np.random.default_rng(seed)
    ground_mat = (
        {"type": "diffuse", "reflectance": _texture(rng)}
        if rng.random() < 0.7
        else {
            "type": "roughplastic",
            "diffuse_reflectance": _texture(rng),
            "alpha": round(float(rng.uniform(0.1, 0.4)), 4),
        }
    )
    if ground_mat.get("reflectance", ground_mat.get("diffuse_reflectance"))["kind"] != "rgb":
        tex = ground_mat.get("reflectance", ground_mat.get("diffuse_reflectance"))
        tex["scale"] = float(rng.choice([6.0, 10.0, 16.0]))
    objects: list[dict] = [{"shape": "ground", "size": 12.0, "material": ground_mat}]
    placed: list[tuple[float, float, float]] = []
    for _ in range(int(rng.integers(3, 7))):
        shape = str(rng.choice(["sphere", "cube", "cylinder", "torus", "panel"]))
        size = float(rng.uniform(0.25, 0.7))
        x, z = _place(rng, placed, size * (1.5 if shape in ("torus", "panel") else 1.0))
        obj: dict = {"shape": shape, "material": _material(rng)}
        if shape == "sphere":
            lift = float(rng.choice([0.0, rng.uniform(0.1, 0.6)]))
            obj |= {"center": [x, size + lift, z], "radius": size}
        elif shape == "cube":
            obj |= {"position": [x, size * 0.8, z], "size": size * 0.8}
            obj["rotation_y"] = float(rng.uniform(0, 90))
        elif shape == "cylinder":
            obj |= {"position": [x, 0.0, z], "radius": size * 0.6}
            obj["height"] = float(rng.uniform(0.5, 2.0) * size)
        elif shape == "torus":
            tilt = float(rng.uniform(0, 90))
            obj |= {"position": [x, size * 0.35 + size * math.sin(math.radians(tilt)), z]}
            obj |= {"major": size, "minor": size * 0.35, "tilt": tilt}
            obj["rotation_y"] = float(rng.uniform(0, 180))
        else:  # panel: an upright two-sided rectangle
            obj |= {"position": [x, size * 1.2, z], "width": size * 1.5, "height": size * 1.2}
            obj["rotation_y"] = float(rng.uniform(0, 180))
        objects.append(obj)

    lights: list[dict] = []
    for _ in range(int(rng.integers(1, 3))):
        tint = np.clip(1.0 + rng.normal(0.0, 0.15, 3), 0.6, 1.4)
        if rng.random() < 0.6:
            ang = rng.uniform(0, 2 * math.pi)
            dist = rng.uniform(1.0, 3.5)
            pos = [dist * math.cos(ang), float(rng.uniform(2.5, 5.0)), dist * math.sin(ang)]
            size = float(rng.uniform(0.3, 1.2))
            power = float(rng.uniform(4.0, 12.0)) * (pos[1] ** 2) / (size * size)
            lights.append(
                {
                    "type": "rectangle",
                    "position": pos,
                    "target": [0.0, 0.0, 0.0],
                    "size": size,
                    "radiance": [round(float(power * c), 3) for c in tint],
                }
            )
        else:
            radius = float(rng.uniform(0.08, 0.3))
            ang = rng.uniform(0, 2 * math.pi)
            dist = rng.uniform(0.5, 3.0)
            center = [dist * math.cos(ang), float(rng.uniform(1.2, 3.5)), dist * math.sin(ang)]
            power = float(rng.uniform(2.0, 8.0)) * (center[1] ** 2) / (radius * radius)
            lights.append(
                {
                    "type": "sphere",
                    "center": center,
                    "radius": radius,
                    "radiance": [round(float(power * c), 3) for c in tint],
                }
            )

    if rng.random() < 0.4:
        env = {"type": "constant", "radiance": _color(rng, 0.05, 0.6)}
    else:
        sun_el = rng.uniform(math.radians(10), math.radians(70))
        sun_az = rng.uniform(0, 2 * math.pi)
        env = {
            "type": "sky",
            "zenith": _color(rng, 0.05, 0.6),
            "horizon": _color(rng, 0.3, 1.0),
            "ground": _color(rng, 0.02, 0.2),
            "sun_dir": [
                math.cos(sun_el) * math.cos(sun_az),
                math.sin(sun_el),
                math.cos(sun_el) * math.sin(sun_az),
            ],
            "sun_radiance": float(rng.uniform(0.0, 30.0)),
            "sun_size_deg": float(rng.uniform(3.0, 10.0)),
            "scale": float(rng.uniform(0.3, 1.5)),
        }
    return {"seed": int(seed), "objects": objects, "lights": lights, "environment": env}


# ---------------------------------------------------------------------------- mitsuba


def _mi_texture(mi, tex: dict) -> dict:
    T = mi.ScalarTransform4f
    if tex["kind"] == "rgb":
        return {"type": "rgb", "value": tex["value"]}
    to_uv = T().scale([tex["scale"], tex["scale"], 1.0])
    if tex["kind"] == "checker":
        return {
            "type": "checkerboard",
            "color0": {"type": "rgb", "value": tex["color0"]},
            "color1": {"type": "rgb", "value": tex["color1"]},
            "to_uv": to_uv,
        }
    img = pattern_texture(
        tex["pattern"], tex["color0"], tex["color1"], tex["seed"], tex.get("size", 128)
    )
    return {"type": "bitmap", "bitmap": mi.Bitmap(img), "to_uv": to_uv}


def _mi_material(mi, m: dict, two_sided: bool = False) -> dict:
    t = m["type"]
    if t == "diffuse":
        d = {"type": t, "reflectance": _mi_texture(mi, m["reflectance"])}
    elif t in ("plastic", "roughplastic"):
        d = {"type": t, "diffuse_reflectance": _mi_texture(mi, m["diffuse_reflectance"])}
        if "alpha" in m:
            d["alpha"] = m["alpha"]
    elif t in DIELECTRICS:
        d = {"type": t, "int_ior": m["int_ior"], "ext_ior": m.get("ext_ior", 1.000277)}
        if "alpha" in m:
            d["alpha"] = m["alpha"]
        if "tint" in m:
            d["specular_transmittance"] = {"type": "rgb", "value": m["tint"]}
        return d  # never two-sided: a dielectric's side is its inside or outside
    elif t in ("conductor", "roughconductor"):
        d = {"type": t, "material": m["material"]}
        if "alpha" in m:
            d["alpha"] = m["alpha"]
    else:
        raise ValueError(f"unknown material type {t!r}")
    return {"type": "twosided", "bsdf": d} if two_sided else d


def _mi_mesh(mi, name: str, mesh: Mesh, bsdf):
    """An `mi.Mesh` with vertex normals from a numpy `Mesh`."""
    props = mi.Properties()
    props["bsdf"] = bsdf
    out = mi.Mesh(name, len(mesh.positions), len(mesh.faces), props, has_vertex_normals=True)
    params = mi.traverse(out)
    for key, arr, dtype in (
        ("vertex_positions", mesh.positions, np.float32),
        ("vertex_normals", mesh.normals, np.float32),
        ("faces", mesh.faces, np.uint32),
    ):
        params[key] = type(params[key])(np.ascontiguousarray(arr, dtype=dtype).ravel())
    params.update()
    return out


def _torus_mesh(
    mi, name: str, major: float, minor: float, matrix: np.ndarray, bsdf, nu: int = 48, nv: int = 24
):
    """A torus (local xz plane, moved by the rigid 4x4 `matrix`) as an `mi.Mesh`, smooth normals."""
    a = np.linspace(0, 2 * np.pi, nu, endpoint=False)[:, None]
    b = np.linspace(0, 2 * np.pi, nv, endpoint=False)[None, :]
    ring = np.stack(
        [np.cos(a) * np.ones_like(b), np.zeros_like(a * b), np.sin(a) * np.ones_like(b)], -1
    )
    normal = ring * np.cos(b)[..., None] + np.array([0.0, 1.0, 0.0]) * np.sin(b)[..., None]
    pos = (major * ring + minor * normal) @ matrix[:3, :3].T + matrix[:3, 3]
    normal = normal @ matrix[:3, :3].T  # rigid: the rotation is orthonormal
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    v00 = i * nv + j
    v10 = ((i + 1) % nu) * nv + j
    v01 = i * nv + (j + 1) % nv
    v11 = ((i + 1) % nu) * nv + (j + 1) % nv
    faces = np.concatenate(
        [np.stack([v00, v01, v10], -1).reshape(-1, 3), np.stack([v10, v01, v11], -1).reshape(-1, 3)]
    )
    return _mi_mesh(mi, name, Mesh(pos.reshape(-1, 3), normal.reshape(-1, 3), faces), bsdf)


def _look_at_up(pos, target) -> list[float]:
    d = np.asarray(target, float) - np.asarray(pos, float)
    d /= np.linalg.norm(d)
    return [0.0, 0.0, 1.0] if abs(d[1]) > 0.99 else [0.0, 1.0, 0.0]


ID_SCALE = 1024.0  # id pass: shape k (1-based) has diffuse reflectance (k / ID_SCALE, 0, 0)


def shape_materials(desc: dict) -> dict[str, dict | None]:
    """Shape key -> material description (None for emitters), in id order (1-based).

    `build_scene(desc, id_pass=True)` gives the k-th shape here the reflectance
    (k / ID_SCALE, 0, 0), so the `albedo` AOV of that scene identifies shapes in
    every variant (Mitsuba's `shape_index` AOV numbers shapes differently in
    scalar and JIT variants).
    """
    table: dict[str, dict | None] = {}
    for k, o in enumerate(desc["objects"]):
        table[_object_key(k, o["shape"])] = o["material"]
        if o["shape"] == "cylinder":
            table[_object_key(k, o["shape"]) + "_cap"] = o["material"]
    for k in range(len(desc["lights"])):
        table[f"light{k}"] = None
    return table


def _object_key(k: int, shape: str) -> str:
    return f"obj{k:02d}_{shape}"


def conductor_f0(mi, material: str) -> np.ndarray:
    """RGB reflectance of a smooth `material` conductor at normal incidence (its albedo)."""
    bsdf = mi.load_dict({"type": "conductor", "material": material})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    _, weight = bsdf.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    return np.clip(np.array(weight, dtype=np.float64).ravel()[:3], 0.0, 1.0)


def build_scene(desc: dict, *, id_pass: bool = False):
    """Load a scene description (from `random_scene`) into an `mi.Scene`.

    With `id_pass`, every shape gets a diffuse BSDF encoding its id (see
    `shape_materials`) and there are no emitters: render it with the `aov`
    integrator's `albedo` to get a per-pixel shape id.
    """
    import mitsuba as mi

    T = mi.ScalarTransform4f
    ids = {key: i + 1 for i, key in enumerate(shape_materials(desc))}

    def bsdf(key: str, mat: dict, two_sided: bool = False) -> dict:
        if id_pass:
            code = ids[key] / ID_SCALE
            return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [code, 0.0, 0.0]}}
        return _mi_material(mi, mat, two_sided)

    d: dict = {"type": "scene"}
    for k, o in enumerate(desc["objects"]):
        shape, mat = o["shape"], o["material"]
        key = _object_key(k, shape)
        if shape == "ground":
            s = o["size"]
            d[key] = {
                "type": "rectangle",
                "to_world": T().rotate([1, 0, 0], -90).scale([s, s, 1]),
                "bsdf": bsdf(key, mat),
            }
        elif shape == "sphere":
            d[key] = {
                "type": "sphere",
                "center": o["center"],
                "radius": o["radius"],
                "bsdf": bsdf(key, mat),
            }
        elif shape == "cube":
            s = o["size"]
            d[key] = {
                "type": "cube",
                "to_world": T()
                .translate(o["position"])
                .rotate([0, 1, 0], o["rotation_y"])
                .scale(s),
                "bsdf": bsdf(key, mat),
            }
        elif shape == "cylinder":
            x, y, z = o["position"]
            h, r = o["height"], o["radius"]
            d[key] = {
                "type": "cylinder",
                "p0": [x, y, z],
                "p1": [x, y + h, z],
                "radius": r,
                "bsdf": bsdf(key, mat, two_sided=True),
            }
            d[key + "_cap"] = {
                "type": "disk",
                "to_world": T().translate([x, y + h, z]).rotate([1, 0, 0], -90).scale(r),
                "bsdf": bsdf(key + "_cap", mat),
            }
        elif shape == "torus":
            to_world = (
                T()
                .translate(o["position"])
                .rotate([0, 1, 0], o["rotation_y"])
                .rotate([1, 0, 0], o["tilt"])
            )
            matrix = np.array(to_world.matrix, dtype=np.float64)
            bsdf_obj = mi.load_dict(bsdf(key, mat))
            d[key] = _torus_mesh(mi, key, o["major"], o["minor"], matrix, bsdf_obj)
        elif shape == "panel":
            w, h = o["width"], o["height"]
            d[key] = {
                "type": "rectangle",
                "to_world": T()
                .translate(o["position"])
                .rotate([0, 1, 0], o["rotation_y"])
                .scale([w / 2, h / 2, 1]),
                "bsdf": bsdf(key, mat, two_sided=True),
            }
        elif shape == "mesh":
            two_sided = o.get("two_sided", mat["type"] not in DIELECTRICS)
            bsdf_obj = mi.load_dict(bsdf(key, mat, two_sided=two_sided))
            d[key] = _mi_mesh(mi, key, mesh_arrays(o["mesh"]), bsdf_obj)
        else:
            raise ValueError(f"unknown shape {shape!r}; expected {SHAPES}")
    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}
    for k, light in enumerate(desc["lights"]):
        key = f"light{k}"
        if light["type"] == "rectangle":
            size = light["size"]
            sx, sy = (size, size) if isinstance(size, (int, float)) else size
            up = _look_at_up(light["position"], light["target"])
            d[key] = {
                "type": "rectangle",
                "to_world": T()
                .look_at(origin=light["position"], target=light["target"], up=up)
                .scale([sx / 2, sy / 2, 1]),
            }
        else:
            d[key] = {"type": "sphere", "center": light["center"], "radius": light["radius"]}
        if id_pass:
            d[key]["bsdf"] = bsdf(key, {})
        else:
            d[key]["bsdf"] = black
            d[key]["emitter"] = {
                "type": "area",
                "radiance": {"type": "rgb", "value": light["radiance"]},
            }
    env = desc["environment"]
    if id_pass or env["type"] == "none":
        pass
    elif env["type"] == "constant":
        d["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": env["radiance"]}}
    else:
        img = sky_envmap(
            env["zenith"],
            env["horizon"],
            env["ground"],
            env["sun_dir"],
            env["sun_radiance"],
            env["sun_size_deg"],
        )
        d["env"] = {"type": "envmap", "bitmap": mi.Bitmap(img), "scale": env["scale"]}
    return mi.load_dict(d)
