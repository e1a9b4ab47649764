"""Pinhole cameras with Mitsuba 3's perspective model, in numpy (no mitsuba import).

Mitsuba's `look_at(origin, target, up)` gives a camera frame with +Z forward,
+Y up and +X **left** (`left = up x forward`). With `fov_axis="x"` its
perspective sensor maps a camera-space point (x_left, y_up, z) to the pixel

    u = W/2 - f * x_left / z,   v = H/2 - f * y_up / z,   f = W / (2 tan(fov/2))

(u right, v down, pixel (i, j) covers [i, i+1) x [j, j+1), centre at +0.5).
The datagen tests check this against positions rendered by Mitsuba itself.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class Camera:
    """One frame's pinhole camera (world units; `fov` in degrees along x)."""

    origin: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float
    width: int
    height: int

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (fov along x)."""
        return self.width / (2.0 * math.tan(math.radians(self.fov) / 2.0))

    def basis(self) -> np.ndarray:
        """3x3 matrix with columns (left, up, forward): Mitsuba's camera-to-world rotation."""
        o = np.asarray(self.origin, np.float64)
        forward = np.asarray(self.target, np.float64) - o
        forward /= np.linalg.norm(forward)
        left = np.cross(np.asarray(self.up, np.float64), forward)
        left /= np.linalg.norm(left)
        up = np.cross(forward, left)
        return np.stack([left, up, forward], axis=1)


def world_to_camera(points: np.ndarray, cam: Camera, *, directions: bool = False) -> np.ndarray:
    """(..., 3) world points (or directions) -> Mitsuba camera space (x left, y up, z forward)."""
    p = np.asarray(points, np.float64)
    if not directions:
        p = p - np.asarray(cam.origin, np.float64)
    return p @ cam.basis()


def project(
    points: np.ndarray, cam: Camera, *, directions: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel coordinates (u right, v down; centres at +0.5) and planar depth z of (..., 3) points.

    Points with z <= 0 (behind the camera) get u = v = NaN.
    """
    c = world_to_camera(points, cam, directions=directions)
    z = c[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(z > 1e-9, 1.0 / z, np.nan)
    f = cam.focal_px
    u = cam.width / 2.0 - f * c[..., 0] * inv
    v = cam.height / 2.0 - f * c[..., 1] * inv
    return u, v, z


def pixel_centres(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) arrays of pixel-centre coordinates u = i + 0.5, v = j + 0.5."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return u, v


def pixel_directions(cam: Camera) -> np.ndarray:
    """(H, W, 3) unit world-space ray directions through the pixel centres."""
    u, v = pixel_centres(cam.width, cam.height)
    f = cam.focal_px
    d_cam = np.stack(
        [-(u - cam.width / 2.0) / f, -(v - cam.height / 2.0) / f, np.ones_like(u)], axis=-1
    )
    d = d_cam @ cam.basis().T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def orbit_path(
    rng: np.random.Generator,
    n_frames: int,
    width: int,
    height: int,
    *,
    target: tuple[float, float, float] = (0.0, 0.5, 0.0),
) -> list[Camera]:
    """A smooth random orbit + dolly + bob around `target`, ~1-2.5 degrees per frame.

    At 64 px width and a 40-60 degree fov that moves scene points a few pixels per frame.
    """
    radius = rng.uniform(2.8, 4.4)
    height0 = rng.uniform(0.9, 2.4)
    theta0 = rng.uniform(0.0, 2.0 * math.pi)
    omega = math.radians(rng.uniform(1.0, 2.5)) * rng.choice([-1.0, 1.0])
    dolly = rng.uniform(-0.04, 0.04) * radius  # radius change per frame
    bob = rng.uniform(0.0, 0.05)  # vertical oscillation amplitude
    bob_phase = rng.uniform(0.0, 2.0 * math.pi)
    fov = float(rng.uniform(40.0, 60.0))
    t_drift = rng.normal(0.0, 0.01, size=3)  # target drift per frame
    t0 = np.asarray(target, np.float64) + rng.normal(0.0, 0.15, size=3) * (1.0, 0.3, 1.0)
    cams = []
    for t in range(n_frames):
        r = max(radius + dolly * t, 2.0)
        th = theta0 + omega * t
        h = height0 + bob * math.sin(bob_phase + 0.5 * t)
        tgt = t0 + t_drift * t
        origin = (tgt[0] + r * math.sin(th), h, tgt[2] + r * math.cos(th))
        cams.append(
            Camera(
                origin=tuple(float(x) for x in origin),
                target=tuple(float(x) for x in tgt),
                up=(0.0, 1.0, 0.0),
                fov=fov,
                width=width,
                height=height,
            )
        )
    return cams
