"""Check a rendered sequence's motion vectors by warping references (numpy only).

For each frame t >= 1 the previous reference is sampled bilinearly at
current pixel centre + motion and compared with the current reference on valid
pixels: in bounds, depth-consistent (warped previous depth within 10 % of the
current one) and away from depth edges in both frames (3x3 neighbourhood within
10 %, current pixel and all four previous taps: there the
box-filtered reference mixes surfaces that the pixel-centre features and motion
do not describe, e.g. the anti-aliased rim of a bright light); the PSNR (on tau-mapped images,
tau(x) = (x / (1 + x))^(1/2.4), Isik21 eq. 14) must rise a lot over the
unwarped previous reference on the same pixels. A wrong sign or axis makes
the warp worse than no warp. Frames that meta.json lists as `cuts` have no previous frame
(their motion is 0, the history is reset) and are not scored.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..runtime.sequences.exr import read_exr

DEPTH_TOLERANCE = 0.1  # relative depth difference still counted as the same surface


def tonemap(x: np.ndarray) -> np.ndarray:
    """tau(x) = (x / (1 + x))^(1/2.4) on non-negative linear radiance."""
    x = np.maximum(x, 0.0)
    return (x / (1.0 + x)) ** (1.0 / 2.4)


def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR (dB, peak 1) of (H, W, C) images over the pixels where `mask` is true."""
    err = (a - b) ** 2
    if mask is not None:
        err = err[mask]
    mse = float(np.mean(err))
    return float("inf") if mse == 0.0 else 10.0 * np.log10(1.0 / mse)


def bilinear_sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample (H, W, C) `img` at pixel coords x, y (centres at +0.5): (values, in_bounds)."""
    h, w = img.shape[:2]
    xs, ys = x - 0.5, y - 0.5
    inb = (xs >= 0) & (xs <= w - 1) & (ys >= 0) & (ys <= h - 1)
    xs, ys = np.clip(xs, 0, w - 1), np.clip(ys, 0, h - 1)
    x0 = np.minimum(np.floor(xs).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(ys).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (xs - x0)[..., None], (ys - y0)[..., None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy, inb


def warp_previous(prev: np.ndarray, motion: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Warp (H, W, C) `prev` onto the current frame with (H, W, 2) motion (prev = cur + motion)."""
    h, w = prev.shape[:2]
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    return bilinear_sample(prev, u + motion[..., 0], v + motion[..., 1])


@dataclass(frozen=True)
class FrameWarp:
    frame: int
    psnr_warped: float
    psnr_static: float
    valid_fraction: float

    @property
    def gain_db(self) -> float:
        return self.psnr_warped - self.psnr_static


def depth_edges(depth: np.ndarray, tol: float = DEPTH_TOLERANCE) -> np.ndarray:
    """(H, W) bool: the 3x3 neighbourhood's depth range exceeds `tol` x the centre depth."""
    p = np.pad(depth, 1, mode="edge")
    h, w = depth.shape
    win = np.stack([p[dy : dy + h, dx : dx + w] for dy in range(3) for dx in range(3)])
    return (win.max(0) - win.min(0)) > tol * depth


def _rgb(ch: dict[str, np.ndarray], prefix: str = "") -> np.ndarray:
    return np.stack([ch[f"{prefix}{c}"] for c in "RGB"], axis=-1).astype(np.float64)


def sequence_cuts(seq_dir: str | os.PathLike) -> set[int]:
    """The cut frames meta.json lists (none without meta.json or `cuts`)."""
    meta = Path(seq_dir) / "meta.json"
    if not meta.is_file():
        return set()
    return {int(t) for t in json.loads(meta.read_text()).get("cuts", [])}


def warp_report(seq_dir: str | os.PathLike) -> list[FrameWarp]:
    """Per-frame warped vs static PSNR of the references of one sequence folder (frames after
    a previous frame of the same shot: not frame 0, not the cuts)."""
    seq = Path(seq_dir)
    frames = sorted(seq.glob("frame_*.exr"))
    if len(frames) < 2:
        raise ValueError(f"{seq}: need at least 2 frames, found {len(frames)}")
    cuts = sequence_cuts(seq)
    out = []
    prev_ref = prev_depth = None
    for path in frames:
        t = int(path.stem.split("_")[1])
        f = read_exr(path)
        ref = tonemap(_rgb(read_exr(seq / f"ref_{t:04d}.exr")))
        depth = f["depth.Z"].astype(np.float64)[..., None]
        if prev_ref is not None and t not in cuts:
            motion = np.stack([f["motion.X"], f["motion.Y"]], axis=-1).astype(np.float64)
            prev_edges = depth_edges(prev_depth[..., 0])[..., None].astype(np.float64)
            stack = np.concatenate([prev_ref, prev_depth, prev_edges], -1)
            warped, inb = warp_previous(stack, motion)
            d_w, edge_w = warped[..., 3], warped[..., 4]
            d = depth[..., 0]
            valid = inb & (np.abs(d_w - d) <= DEPTH_TOLERANCE * d)
            valid &= ~depth_edges(d) & (edge_w == 0.0)
            out.append(
                FrameWarp(
                    frame=t,
                    psnr_warped=psnr(warped[..., :3], ref, valid) if valid.any() else np.nan,
                    psnr_static=psnr(prev_ref, ref, valid) if valid.any() else np.nan,
                    valid_fraction=float(valid.mean()),
                )
            )
        prev_ref, prev_depth = ref, depth
    return out


def warp_gain_db(seq_dir: str | os.PathLike) -> float:
    """Mean PSNR gain (dB) of motion-warped over unwarped previous references, over the frames
    with valid pixels (NaN when none has: e.g. a fast pan where nothing stays in view)."""
    gains = [r.gain_db for r in warp_report(seq_dir) if r.valid_fraction > 0]
    return float(np.mean(gains)) if gains else float("nan")
