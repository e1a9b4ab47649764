"""A small synthetic training sequence in the canonical EXR layout, for the training tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rtdenoise.runtime.sequences.exr import write_exr

INPUTS = ("color", "albedo", "normal", "depth", "motion")
TINY = {"widths": [8, 12], "kernel_size": 5, "refine_width": 8}


def write_sequence(
    folder: Path, frames: int = 6, size: int = 32, seed: int = 0, color_b: bool = False
) -> Path:
    """A faceted, textured wall panning 1 px per frame (previous = current + (1, 0)).

    Shading follows the facet normals, so a denoiser that learns to use the normal
    feature beats the blur an untrained one does; noise is 1-spp-like (exponential).
    `color_b`: also a second, independent estimate (colorB, crossreg's input).
    """
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float32)
    light = np.array([0.6, -0.3, 0.74], np.float32)
    for t in range(frames):
        u = xs + t
        tilt = ((np.floor(u / 3) + np.floor(ys / 5)) % 3 - 1.0) * 0.8
        normal = np.stack([np.sin(tilt), np.zeros_like(tilt), np.cos(tilt)])
        albedo = 0.3 + 0.5 * (np.floor(u / 8) % 2)
        ref = albedo * (0.05 + 2.0 * np.maximum(0.0, np.tensordot(light, normal, 1)))
        noisy = ref * rng.exponential(1.0, size=(3, size, size)).astype(np.float32)
        ch = {c: noisy[i] for i, c in enumerate("RGB")}
        if color_b:
            noisy_b = ref * rng.exponential(1.0, size=(3, size, size)).astype(np.float32)
            ch.update({f"colorB.{c}": noisy_b[i] for i, c in enumerate("RGB")})
        ch.update({f"albedo.{c}": albedo for c in "RGB"})
        ch.update({f"normal.{c}": normal[i] for i, c in enumerate("XYZ")})
        ch["depth.Z"] = np.full_like(xs, 3.0)
        ch["motion.X"], ch["motion.Y"] = np.ones_like(xs), np.zeros_like(xs)
        write_exr(folder / f"frame_{t:04d}.exr", ch, half=False)
        write_exr(folder / f"ref_{t:04d}.exr", {c: ref for c in "RGB"}, half=False)
    return folder
