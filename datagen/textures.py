"""Procedural images made with numpy: surface textures and a sky environment map.

Everything is deterministic in its parameters (including an integer `seed`), so a
scene description in meta.json is enough to rebuild its textures.
"""

from __future__ import annotations

import math

import numpy as np

PATTERNS = ("stripes", "noise", "grid", "dots")
# High-frequency patterns (the `texture` and `thin` scene kinds); kept apart from PATTERNS,
# which the `legacy` generator draws from, so that its scenes stay what they were.
HF_PATTERNS = ("text", "fine_stripes", "fine_checker", "fine_noise")
ALL_PATTERNS = PATTERNS + HF_PATTERNS


def _value_noise(rng: np.random.Generator, size: int, octaves: int = 4) -> np.ndarray:
    """Tileable-ish fractal value noise in [0, 1], (size, size)."""
    out = np.zeros((size, size))
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 4 * 2**o
        grid = rng.random((cells + 1, cells + 1))
        grid[-1, :], grid[:, -1] = grid[0, :], grid[:, 0]
        x = np.linspace(0.0, cells, size, endpoint=False)
        i = np.floor(x).astype(int)
        t = x - i
        t = t * t * (3.0 - 2.0 * t)  # smoothstep
        rows = grid[i] * (1 - t)[:, None] + grid[i + 1] * t[:, None]
        out += amp * (rows[:, i] * (1 - t)[None, :] + rows[:, i + 1] * t[None, :])
        total += amp
        amp *= 0.5
    return out / total


def pattern_texture(
    pattern: str,
    color0: list[float],
    color1: list[float],
    seed: int,
    size: int = 128,
) -> np.ndarray:
    """(size, size, 3) float32 texture in [0, 1] mixing two colours with a pattern mask."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    if pattern == "stripes":
        ang = rng.uniform(0.0, math.pi)
        freq = rng.integers(3, 9)
        s = np.sin(2 * math.pi * freq * (x * math.cos(ang) + y * math.sin(ang)))
        mask = 0.5 + 0.5 * np.tanh(4.0 * s)
    elif pattern == "noise":
        mask = _value_noise(rng, size)
        mask = np.clip((mask - mask.min()) / max(np.ptp(mask), 1e-6), 0.0, 1.0)
    elif pattern == "grid":
        n = rng.integers(4, 10)
        w = rng.uniform(0.06, 0.2)
        fx, fy = (x * n) % 1.0, (y * n) % 1.0
        mask = ((fx < w) | (fy < w)).astype(np.float64)
    elif pattern == "dots":
        n = rng.integers(3, 8)
        fx, fy = (x * n) % 1.0 - 0.5, (y * n) % 1.0 - 0.5
        mask = (fx * fx + fy * fy < rng.uniform(0.04, 0.16)).astype(np.float64)
    elif pattern in HF_PATTERNS:
        mask = _hf_mask(pattern, rng, size)
    else:
        raise ValueError(f"unknown pattern {pattern!r}; expected one of {ALL_PATTERNS}")
    c0, c1 = np.asarray(color0), np.asarray(color1)
    tex = c0 * (1.0 - mask[..., None]) + c1 * mask[..., None]
    return np.ascontiguousarray(np.clip(tex, 0.0, 1.0), dtype=np.float32)


def _text_mask(rng: np.random.Generator, size: int) -> np.ndarray:
    """Lines of random 3x5 glyphs (1-pixel strokes at 4 texels per glyph pixel): text-like."""
    cell = max(1, size // 128)  # texels per glyph pixel
    gw, gh = 4 * cell, 7 * cell  # glyph cell with spacing
    glyphs = rng.random((32, 5, 3)) < 0.55
    mask = np.zeros((size, size))
    for row in range(size // gh):
        line = rng.integers(0, 32, size=size // gw)
        line[rng.random(len(line)) < 0.15] = -1  # word gaps
        for col, g in enumerate(line):
            if g < 0:
                continue
            block = np.kron(glyphs[g], np.ones((cell, cell)))
            y0, x0 = row * gh + cell, col * gw
            mask[y0 : y0 + 5 * cell, x0 : x0 + 3 * cell] = block
    return mask


def _hf_mask(pattern: str, rng: np.random.Generator, size: int) -> np.ndarray:
    """Masks with detail near the texel scale (aliasing-prone once minified)."""
    y, x = np.mgrid[0:size, 0:size] / size
    if pattern == "text":
        return _text_mask(rng, size)
    if pattern == "fine_stripes":
        ang = rng.uniform(0.0, math.pi)
        freq = rng.integers(20, 48)
        s = np.sin(2 * math.pi * freq * (x * math.cos(ang) + y * math.sin(ang)))
        return (s > 0).astype(np.float64)
    if pattern == "fine_checker":
        n = int(rng.integers(16, 40))
        return ((np.floor(x * n) + np.floor(y * n)) % 2).astype(np.float64)
    noise = _value_noise(rng, size, octaves=7)  # fine_noise: thresholded, sharp-edged blobs
    return (noise > np.median(noise)).astype(np.float64)


def sky_envmap(
    zenith: list[float],
    horizon: list[float],
    ground: list[float],
    sun_dir: list[float],
    sun_radiance: float,
    sun_size_deg: float,
    height: int = 64,
) -> np.ndarray:
    """(height, 2*height, 3) float32 lat-long sky in Mitsuba's envmap layout.

    Row 0 is +Y (up), u wraps the azimuth. A gradient from horizon to zenith, a
    darker ground and a soft sun lobe around `sun_dir` (unit world vector).
    """
    width = 2 * height
    v, u = np.mgrid[0:height, 0:width]
    theta = (v + 0.5) / height * math.pi  # 0 at +Y
    phi = (u + 0.5) / width * 2.0 * math.pi
    # Mitsuba envmap: d = (sin(theta) sin(phi), cos(theta), -sin(theta) cos(phi))
    d = np.stack(
        [np.sin(theta) * np.sin(phi), np.cos(theta), -np.sin(theta) * np.cos(phi)], axis=-1
    )
    up = np.clip(d[..., 1], -1.0, 1.0)
    t = np.clip(up, 0.0, 1.0)[..., None] ** 0.5
    sky = np.asarray(horizon) * (1 - t) + np.asarray(zenith) * t
    sky = np.where((up < 0)[..., None], np.asarray(ground), sky)
    s = np.asarray(sun_dir, np.float64)
    s /= np.linalg.norm(s)
    cos_sun = np.clip(d @ s, -1.0, 1.0)
    width_rad = math.radians(sun_size_deg)
    lobe = np.exp(-((np.arccos(cos_sun) / width_rad) ** 2))
    sky = sky + sun_radiance * lobe[..., None]
    return np.ascontiguousarray(sky, dtype=np.float32)
