"""Camera paths as JSON specs: still, pan, dolly, orbit, fast, and cuts between shots.

A scene kind draws a path spec with `draw_path(rng, anchor, weights)` (numpy only); the spec
lives in the scene description (`desc["camera"]`), and `cameras_from_spec(spec, frames, W, H)`
turns it into one `Camera` per frame and the cut frames. A spec is
`{"shots": [shot, ...], "cut_fractions": [f, ...]}`: shot k starts at frame
`cut_frames(...)[k - 1]`; at a cut the camera jumps to a new viewpoint of the same scene, the
sequence's meta.json marks the frame (`cuts`, `reset`) and its motion vectors are 0 like
frame 0's (docs/contract.md: `reset = 1` at a camera cut; the history is not used).

A shot: `{"path": one of PATHS, "origin", "target", "fov", ...rates}`, the camera at local
frame t (frames since the shot began):
- still: fixed;
- pan: fixed origin, the view turns about the vertical axis by `yaw_rate` degrees per frame
  and tilts by `pitch_rate`;
- dolly: the origin moves towards the target by `speed` world units per frame (negative:
  away), stopping at `min_distance`;
- orbit: the origin turns about the target's vertical axis by `omega` degrees per frame, its
  horizontal distance changing by `radius_rate` per frame;
- fast: origin and target move together by `velocity` (world units per frame) while the view
  turns by `yaw_rate` (several degrees per frame): large motion, much disocclusion.

An anchor says where a kind's camera may stand: `{"mode": "orbit", "target": [x, y, z],
"target_jitter": j, "radius": [lo, hi], "height": [lo, hi]}` (outdoor: around a point) or
`{"mode": "box", "origin_box": [[x0, y0, z0], [x1, y1, z1]], "target_box": [...]}` (interiors:
inside a room); `bounds` (optional, [[lo], [hi]]) clamps every origin (walls stay outside).
"""

from __future__ import annotations

import math

import numpy as np

from .camera import Camera

PATHS = ("still", "pan", "dolly", "orbit", "fast")
DEFAULT_PATH_WEIGHTS = {"still": 0.12, "pan": 0.2, "dolly": 0.2, "orbit": 0.33, "fast": 0.15}
CUT_PROBABILITY = 0.2


def _r(x: float) -> float:
    return round(float(x), 5)


def _vec(v) -> list[float]:
    return [_r(a) for a in v]


def _viewpoint(rng: np.random.Generator, anchor: dict) -> tuple[np.ndarray, np.ndarray]:
    """A random (origin, target) allowed by `anchor`."""
    if anchor["mode"] == "orbit":
        tgt = np.asarray(anchor["target"], np.float64)
        tgt = tgt + rng.normal(0.0, anchor.get("target_jitter", 0.15), 3) * (1.0, 0.3, 1.0)
        r = rng.uniform(*anchor["radius"])
        th = rng.uniform(0.0, 2.0 * math.pi)
        origin = np.array([tgt[0] + r * math.sin(th), rng.uniform(*anchor["height"]),
                           tgt[2] + r * math.cos(th)])  # fmt: skip
        return origin, tgt
    if anchor["mode"] == "box":
        lo, hi = (np.asarray(a, np.float64) for a in anchor["origin_box"])
        tlo, thi = (np.asarray(a, np.float64) for a in anchor["target_box"])
        origin = rng.uniform(lo, hi)
        targets = rng.uniform(tlo, thi, size=(6, 3))  # the farthest of 6: a view into the room
        tgt = targets[int(np.argmax(np.linalg.norm(targets - origin, axis=1)))]
        return origin, tgt
    raise ValueError(f"unknown camera anchor mode {anchor['mode']!r}; expected orbit or box")


def draw_shot(
    rng: np.random.Generator, anchor: dict, path: str, fov: tuple[float, float] = (40.0, 65.0)
) -> dict:
    """One shot of type `path` from a viewpoint the anchor allows."""
    origin, target = _viewpoint(rng, anchor)
    shot: dict = {"path": path, "origin": _vec(origin), "target": _vec(target)}
    shot["fov"] = _r(rng.uniform(*fov))
    dist = float(np.linalg.norm(target - origin))
    sign = float(rng.choice([-1.0, 1.0]))
    if path == "pan":
        shot["yaw_rate"] = _r(sign * rng.uniform(0.6, 2.5))
        shot["pitch_rate"] = _r(rng.normal(0.0, 0.3))
    elif path == "dolly":
        shot["speed"] = _r(float(rng.choice([1.0, -0.6])) * rng.uniform(0.015, 0.05) * dist)
        shot["min_distance"] = _r(0.35 * dist)
    elif path == "orbit":
        shot["omega"] = _r(sign * rng.uniform(1.0, 2.5))
        shot["radius_rate"] = _r(rng.uniform(-0.04, 0.04) * dist)
    elif path == "fast":
        v = rng.normal(0.0, 1.0, 3) * (1.0, 0.2, 1.0)
        shot["velocity"] = _vec(v / np.linalg.norm(v) * rng.uniform(0.06, 0.15) * dist)
        shot["yaw_rate"] = _r(sign * rng.uniform(4.0, 9.0))
    elif path != "still":
        raise ValueError(f"unknown camera path {path!r}; expected one of {PATHS}")
    return shot


def draw_path(
    rng: np.random.Generator,
    anchor: dict,
    weights: dict[str, float] | None = None,
    *,
    cut_probability: float = CUT_PROBABILITY,
    fov: tuple[float, float] = (40.0, 65.0),
) -> dict:
    """A path spec: one shot, or (with `cut_probability`) two shots with a cut between them."""
    weights = weights or DEFAULT_PATH_WEIGHTS
    names = list(weights)
    p = np.asarray([weights[n] for n in names], np.float64)
    n_shots = 2 if rng.random() < cut_probability else 1
    shots = [draw_shot(rng, anchor, str(rng.choice(names, p=p / p.sum())), fov)
             for _ in range(n_shots)]  # fmt: skip
    spec: dict = {"shots": shots, "cut_fractions": []}
    if n_shots == 2:
        spec["cut_fractions"] = [_r(rng.uniform(0.3, 0.7))]
    if "bounds" in anchor:
        spec["bounds"] = [_vec(anchor["bounds"][0]), _vec(anchor["bounds"][1])]
    return spec


def cut_frames(spec: dict, frames: int) -> list[int]:
    """Frames where a new shot begins (sorted, in [1, frames - 1])."""
    if frames < 2:
        return []
    cuts = {min(max(int(round(f * frames)), 1), frames - 1) for f in spec.get("cut_fractions", [])}
    return sorted(cuts)[: len(spec["shots"]) - 1]


def _turn_y(v: np.ndarray, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


def shot_pose(shot: dict, t: int) -> tuple[np.ndarray, np.ndarray]:
    """(origin, target) of a shot at local frame t."""
    o = np.asarray(shot["origin"], np.float64)
    g = np.asarray(shot["target"], np.float64)
    path = shot["path"]
    if path == "still":
        return o, g
    if path == "pan":
        d = _turn_y(g - o, shot["yaw_rate"] * t)
        horiz = math.hypot(d[0], d[2])
        elev = math.atan2(d[1], horiz) + math.radians(shot.get("pitch_rate", 0.0) * t)
        elev = max(min(elev, math.radians(60)), math.radians(-60))
        norm = np.linalg.norm(d)
        d = np.array([d[0] / horiz * math.cos(elev), math.sin(elev), d[2] / horiz * math.cos(elev)])
        return o, o + d * norm
    if path == "dolly":
        d = g - o
        dist = float(np.linalg.norm(d))
        step = min(shot["speed"] * t, dist - shot["min_distance"])
        return o + d / dist * step, g
    if path == "orbit":
        rel = _turn_y(o - g, shot["omega"] * t)
        horiz = math.hypot(rel[0], rel[2])
        scale = max(horiz + shot["radius_rate"] * t, 0.3 * horiz) / horiz
        return g + rel * np.array([scale, 1.0, scale]), g
    if path == "fast":
        v = np.asarray(shot["velocity"], np.float64) * t
        return o + v, o + v + _turn_y(g - o, shot["yaw_rate"] * t)
    raise ValueError(f"unknown camera path {path!r}; expected one of {PATHS}")


def cameras_from_spec(
    spec: dict, frames: int, width: int, height: int
) -> tuple[list[Camera], list[int]]:
    """One camera per frame and the cut frames of a path spec."""
    cuts = cut_frames(spec, frames)
    starts = [0, *cuts]
    bounds = spec.get("bounds")
    cams = []
    for t in range(frames):
        k = max(i for i, s in enumerate(starts) if s <= t)
        shot = spec["shots"][k]
        origin, target = shot_pose(shot, t - starts[k])
        if bounds is not None:
            shift = np.clip(origin, bounds[0], bounds[1]) - origin
            origin, target = origin + shift, target + shift
        up = (0.0, 1.0, 0.0)
        cams.append(Camera(tuple(float(x) for x in origin), tuple(float(x) for x in target),
                           up, float(shot["fov"]), width, height))  # fmt: skip
    return cams, cuts
