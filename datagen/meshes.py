"""Triangle meshes made with numpy from small JSON specs (no mitsuba import).

A scene description holds a mesh as its generating parameters (`{"kind": "grille", ...}`),
never as vertices, so meta.json stays small and `mesh_arrays(spec)` rebuilds the same mesh.
Every builder returns `Mesh(positions (V, 3), normals (V, 3), faces (F, 3))` with faces wound
counter-clockwise around their normals (geometric and shading normal agree, which dielectrics
need to tell inside from outside).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MESH_KINDS = ("box", "boxes", "grille", "foliage", "room", "heightfield", "wires", "deck")


@dataclass(frozen=True)
class Mesh:
    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray


def merge(meshes: list[Mesh]) -> Mesh:
    """One mesh from several (vertex indices shifted)."""
    offset, faces = 0, []
    for m in meshes:
        faces.append(m.faces + offset)
        offset += len(m.positions)
    return Mesh(
        np.concatenate([m.positions for m in meshes]),
        np.concatenate([m.normals for m in meshes]),
        np.concatenate(faces),
    )


def _rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def quad(corner: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray) -> Mesh:
    """A parallelogram corner, corner + u, corner + u + v, corner + v; normal u x v."""
    c, u, v = (np.asarray(a, np.float64) for a in (corner, edge_u, edge_v))
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    pos = np.stack([c, c + u, c + u + v, c + v])
    return Mesh(pos, np.tile(n, (4, 1)), np.array([[0, 1, 2], [0, 2, 3]]))


def box(center, size, rotation_y: float = 0.0) -> Mesh:
    """An axis-aligned box of `size` (sx, sy, sz), turned about y, outward flat normals."""
    h = np.asarray(size, np.float64) / 2
    r = _rot_y(rotation_y)
    faces = []
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            corner = np.zeros(3)
            corner[axis] = sign * h[axis]
            corner[a], corner[b] = -h[a], -h[b]
            u, v = np.zeros(3), np.zeros(3)
            u[a], v[b] = 2 * h[a], 2 * h[b]
            if sign < 0:
                u, v = v, u
            faces.append(quad(corner, u, v))
    m = merge(faces)
    return Mesh(m.positions @ r.T + np.asarray(center, np.float64), m.normals @ r.T, m.faces)


def tube(p0, p1, radius: float, segments: int = 8) -> Mesh:
    """An open cylinder (smooth normals) from p0 to p1."""
    p0, p1 = np.asarray(p0, np.float64), np.asarray(p1, np.float64)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    w = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    a = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    ring = np.cos(a)[:, None] * u + np.sin(a)[:, None] * v
    pos = np.concatenate([p0 + radius * ring, p1 + radius * ring])
    nrm = np.concatenate([ring, ring])
    i = np.arange(segments)
    j = (i + 1) % segments
    faces = np.concatenate(
        [np.stack([i, j, j + segments], -1), np.stack([i, j + segments, i + segments], -1)]
    )
    return Mesh(pos, nrm, faces)


def grille(spec: dict) -> Mesh:
    """Parallel thin bars (boxes or tubes) in a frame: `center`, `width`, `height`, `bars`,
    `thickness`, `rotation_y`, `round` (tubes), `cross` (bars both ways)."""
    w, h, n, t = spec["width"], spec["height"], int(spec["bars"]), spec["thickness"]
    parts = []
    for k in range(n):
        x = -w / 2 + (k + 0.5) * w / n
        if spec.get("round"):
            parts.append(tube([x, -h / 2, 0.0], [x, h / 2, 0.0], t / 2))
        else:
            parts.append(box([x, 0.0, 0.0], [t, h, t]))
    if spec.get("cross"):
        m = max(2, int(round(n * h / w)))
        for k in range(m):
            y = -h / 2 + (k + 0.5) * h / m
            if spec.get("round"):
                parts.append(tube([-w / 2, y, t], [w / 2, y, t], t / 2))
            else:
                parts.append(box([0.0, y, t], [w, t, t]))
    for y in (-h / 2, h / 2):  # the frame
        parts.append(box([0.0, y, 0.0], [w + 2 * t, 2 * t, 2 * t]))
    mesh = merge(parts)
    r = _rot_y(spec.get("rotation_y", 0.0))
    centre = np.asarray(spec["center"], np.float64)
    return Mesh(mesh.positions @ r.T + centre, mesh.normals @ r.T, mesh.faces)


def _leaf(rng: np.random.Generator, base: np.ndarray, size: float) -> Mesh:
    """A flat pointed leaf (a fan of 6 triangles) at `base`, random orientation."""
    d = rng.normal(size=3)
    d[1] = abs(d[1]) * 0.5
    d /= np.linalg.norm(d)
    side = np.cross(d, rng.normal(size=3))
    side /= np.linalg.norm(side)
    n = np.cross(d, side)
    t = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
    width = np.sin(np.pi * t) * 0.35
    spine = base + size * t[:, None] * d
    left = spine + size * width[:, None] * side
    right = spine - size * width[:, None] * side
    pos = np.concatenate([spine[[0, 4]], left[1:4], right[1:4]])  # 0 base, 1 tip, 2-4 L, 5-7 R
    faces = np.array([[0, 2, 3], [0, 3, 4], [0, 4, 1], [0, 1, 7], [0, 7, 6], [0, 6, 5]])
    return Mesh(pos, np.tile(n, (len(pos), 1)), _orient(pos, faces, n))


def _orient(pos: np.ndarray, faces: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Flip triangles whose geometric normal points away from `n`."""
    e = np.cross(pos[faces[:, 1]] - pos[faces[:, 0]], pos[faces[:, 2]] - pos[faces[:, 0]])
    bad = e @ n < 0
    out = faces.copy()
    out[bad] = out[bad][:, [0, 2, 1]]
    return out


def foliage(spec: dict) -> Mesh:
    """A bush: `leaves` leaves of `leaf_size` on thin stems in a ball (`center`, `radius`),
    drawn from `seed`."""
    rng = np.random.default_rng(int(spec["seed"]))
    c = np.asarray(spec["center"], np.float64)
    parts = []
    for _ in range(int(spec["leaves"])):
        p = rng.normal(size=3)
        p = c + p / np.linalg.norm(p) * spec["radius"] * rng.uniform(0.3, 1.0) ** 0.5
        parts.append(_leaf(rng, p, spec["leaf_size"] * rng.uniform(0.7, 1.3)))
    for _ in range(int(spec.get("stems", 5))):
        top = c + rng.normal(size=3) * spec["radius"] * 0.4
        parts.append(tube([c[0], 0.0, c[2]], top, spec["leaf_size"] * 0.06, segments=6))
    return merge(parts)


def wall_with_holes(
    corner: np.ndarray, edge_u: np.ndarray, edge_v: np.ndarray, holes: list[list[float]]
) -> Mesh:
    """A rectangle (normal u x v) without the holes `[u0, v0, u1, v1]` (fractions of u, v):
    cut into a grid by every hole edge, cells inside a hole left out."""
    us = sorted({0.0, 1.0, *[h[0] for h in holes], *[h[2] for h in holes]})
    vs = sorted({0.0, 1.0, *[h[1] for h in holes], *[h[3] for h in holes]})
    corner, edge_u, edge_v = (np.asarray(a, np.float64) for a in (corner, edge_u, edge_v))
    parts = []
    for a0, a1 in zip(us[:-1], us[1:], strict=True):
        for b0, b1 in zip(vs[:-1], vs[1:], strict=True):
            mu, mv = (a0 + a1) / 2, (b0 + b1) / 2
            if any(h[0] <= mu <= h[2] and h[1] <= mv <= h[3] for h in holes):
                continue
            parts.append(quad(corner + a0 * edge_u + b0 * edge_v, (a1 - a0) * edge_u,
                              (b1 - b0) * edge_v))  # fmt: skip
    return merge(parts)


ROOM_WALLS = ("floor", "ceiling", "x-", "x+", "z-", "z+")


def room(spec: dict) -> Mesh:
    """The inside of a box room (normals inward): `center` (floor centre), `size` (sx, sy, sz),
    `openings` [{"wall": one of ROOM_WALLS, "rect": [u0, v0, u1, v1]}], `walls` (which to
    build, default all)."""
    sx, sy, sz = spec["size"]
    c = np.asarray(spec["center"], np.float64) + np.array([-sx / 2, 0.0, -sz / 2])
    X, Y, Z = np.array([sx, 0.0, 0.0]), np.array([0.0, sy, 0.0]), np.array([0.0, 0.0, sz])
    frames = {  # corner, u, v with u x v pointing into the room
        "floor": (c, Z, X),
        "ceiling": (c + Y, X, Z),
        "x-": (c, Y, Z),
        "x+": (c + X, Z, Y),
        "z-": (c, X, Y),
        "z+": (c + Z, Y, X),
    }
    holes: dict[str, list] = {w: [] for w in ROOM_WALLS}
    for o in spec.get("openings", []):
        holes[o["wall"]].append(o["rect"])
    walls = spec.get("walls", ROOM_WALLS)
    return merge([wall_with_holes(*frames[w], holes[w]) for w in walls])


def heightfield(spec: dict) -> Mesh:
    """A wavy surface y = y0 + sum_k a_k sin(k . (x, z) + phase_k) over `size` (sx, sz) at
    `center`, `resolution` cells per side, analytic normals (up)."""
    n = int(spec["resolution"])
    sx, sz = spec["size"]
    cx, y0, cz = spec["center"]
    x, z = np.meshgrid(np.linspace(-sx / 2, sx / 2, n + 1), np.linspace(-sz / 2, sz / 2, n + 1))
    y = np.full_like(x, y0)
    dydx, dydz = np.zeros_like(x), np.zeros_like(x)
    for amp, kx, kz, ph in spec["waves"]:
        arg = kx * x + kz * z + ph
        y += amp * np.sin(arg)
        dydx += amp * kx * np.cos(arg)
        dydz += amp * kz * np.cos(arg)
    pos = np.stack([x + cx, y, z + cz], -1).reshape(-1, 3)
    nrm = np.stack([-dydx, np.ones_like(x), -dydz], -1).reshape(-1, 3)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")  # i: z row, j: x column
    v00 = i * (n + 1) + j
    v01, v10, v11 = v00 + 1, v00 + n + 1, v00 + n + 2
    faces = np.concatenate(
        [np.stack([v00, v10, v01], -1).reshape(-1, 3), np.stack([v01, v10, v11], -1).reshape(-1, 3)]
    )
    return Mesh(pos, nrm, _orient(pos, faces, np.array([0.0, 1.0, 0.0])))


def wires(spec: dict) -> Mesh:
    """Thin straight wires (tubes of `radius`) between the point pairs `segments`."""
    return merge([tube(a, b, spec["radius"], segments=6) for a, b in spec["segments"]])


def boxes(spec: dict) -> Mesh:
    """Several boxes `[[center, size, rotation_y], ...]` as one mesh."""
    return merge([box(c, s, r) for c, s, r in spec["boxes"]])


def deck(spec: dict) -> Mesh:
    """A horizontal square (normal up) of side `size` at height `y` with a rectangular `hole`
    [x0, z0, x1, z1] (world units): the ground around a pool."""
    size, y = spec["size"], spec["y"]
    x0, z0, x1, z1 = spec["hole"]
    corner = np.array([-size / 2, y, -size / 2])
    frac = [(z0 + size / 2) / size, (x0 + size / 2) / size, (z1 + size / 2) / size,
            (x1 + size / 2) / size]  # fmt: skip
    return wall_with_holes(corner, np.array([0.0, 0.0, size]), np.array([size, 0.0, 0.0]), [frac])


def mesh_arrays(spec: dict) -> Mesh:
    """Build the mesh a spec describes (`kind` one of MESH_KINDS)."""
    kind = spec["kind"]
    if kind == "box":
        return box(spec["center"], spec["size"], spec.get("rotation_y", 0.0))
    builders = {
        "boxes": boxes,
        "grille": grille,
        "foliage": foliage,
        "room": room,
        "heightfield": heightfield,
        "wires": wires,
        "deck": deck,
    }
    if kind not in builders:
        raise ValueError(f"unknown mesh kind {kind!r}; expected one of {MESH_KINDS}")
    return builders[kind](spec)
