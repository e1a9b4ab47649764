"""Turn Mitsuba's raw AOVs into the canonical feature buffers (numpy only).

Conventions (written into every meta.json as well):
- `albedo`: the `aov` integrator's albedo clamped to [0, 1], except conductors
  (their RGB reflectance at normal incidence, like OIDN's guidance for metals)
  and emitters (1); background 1.
- `normal`: shading normal in camera space, x right, y up, z towards the camera
  (OpenGL style), flipped to face the camera; background 0.
- `depth`: planar view depth (distance along the camera's forward axis, world
  units); background `BACKGROUND_DEPTH`.
- `motion`: pixels, previous position = current position + motion, x right,
  y down. Surfaces: the world position projected with the previous camera.
  Background: the environment direction projected with the previous camera
  (rotation only). Frame 0 (no previous frame): 0.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera, pixel_centres, pixel_directions, project, world_to_camera

BACKGROUND_DEPTH = 1.0e4
BACKGROUND_ALBEDO = 1.0


def override_albedo(albedo: np.ndarray, ids: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Replace the albedo of whole shapes: `table[k]` is RGB for shape id k, or NaN to keep.

    `ids` is the (H, W) integer shape id (0 = miss).
    """
    idx = np.clip(ids, 0, len(table) - 1)
    ov = table[idx]
    return np.where(np.isnan(ov), albedo, ov)


def camera_space_normals(normals: np.ndarray, cam: Camera, facing: np.ndarray) -> np.ndarray:
    """World normals (H, W, 3) -> camera space (x right, y up, z towards camera), unit length.

    `facing` holds the world view directions (camera -> point); normals are flipped
    so that they point back towards the camera.
    """
    n = np.asarray(normals, np.float64)
    n = np.where((np.sum(n * facing, axis=-1) > 0)[..., None], -n, n)
    c = world_to_camera(n, cam, directions=True)  # (x left, y up, z forward)
    c = np.stack([-c[..., 0], c[..., 1], -c[..., 2]], axis=-1)
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    return np.where(norm > 1e-12, c / np.maximum(norm, 1e-12), 0.0)


def motion_vectors(
    position: np.ndarray, hit: np.ndarray, cam: Camera, prev: Camera | None
) -> np.ndarray:
    """(H, W, 2) motion in pixels: previous pixel = current pixel centre + motion."""
    if prev is None:
        return np.zeros(hit.shape + (2,), np.float64)
    u0, v0 = pixel_centres(cam.width, cam.height)
    u_s, v_s, _ = project(position, prev)
    u_b, v_b, _ = project(pixel_directions(cam), prev, directions=True)
    u = np.where(hit, u_s, u_b)
    v = np.where(hit, v_s, v_b)
    mv = np.stack([u - u0, v - v0], axis=-1)
    return np.nan_to_num(mv, nan=0.0, posinf=0.0, neginf=0.0)


def canonical_features(
    albedo: np.ndarray,
    normal: np.ndarray,
    position: np.ndarray,
    hit: np.ndarray,
    cam: Camera,
    prev: Camera | None,
) -> dict[str, np.ndarray]:
    """Canonical EXR channels (2-D float32) from the AOVs of one frame.

    albedo, normal (world shading normal) and position are (H, W, 3); hit is (H, W) bool.
    """
    hit = np.asarray(hit, bool)
    dirs = pixel_directions(cam)
    alb = np.where(hit[..., None], np.clip(np.nan_to_num(albedo), 0.0, 1.0), BACKGROUND_ALBEDO)
    nrm = np.where(hit[..., None], camera_space_normals(np.nan_to_num(normal), cam, dirs), 0.0)
    _, _, z = project(position, cam)
    depth = np.where(hit, np.maximum(np.nan_to_num(z), 0.0), BACKGROUND_DEPTH)
    mv = motion_vectors(position, hit, cam, prev)
    out: dict[str, np.ndarray] = {}
    for i, c in enumerate("RGB"):
        out[f"albedo.{c}"] = alb[..., i]
    for i, c in enumerate("XYZ"):
        out[f"normal.{c}"] = nrm[..., i]
    out["depth.Z"] = depth
    out["motion.X"] = mv[..., 0]
    out["motion.Y"] = mv[..., 1]
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in out.items()}
