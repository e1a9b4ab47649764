"""8-bit PNG previews of linear HDR images (tau tonemap, Isik21 eq. 15).

Pillow is not a dependency, so this is a minimal PNG writer (RGB, 8 bits, no
interlace, zlib from the standard library), written atomically (temp + rename).
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

import numpy as np

from .atomic import write_bytes_atomic


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    """(3, H, W) linear HDR -> (H, W, 3) uint8: tau (Isik21 eq. 15) in float32, rounded;
    NaN -> 0, +Inf -> 255."""
    x = np.maximum(np.nan_to_num(np.asarray(rgb, dtype=np.float32), nan=0.0), np.float32(0))
    tau = np.power(x / (1 + x), np.float32(1 / 2.4))  # Inf became float32 max: tau = 1
    scaled = np.clip(np.rint(tau * np.float32(255)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(scaled.transpose(1, 2, 0))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def encode_png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 image (filter type 0 on every row)."""
    h, w, c = pixels.shape
    if c != 3 or pixels.dtype != np.uint8:
        raise ValueError(f"encode_png: expected (H, W, 3) uint8, got {pixels.shape} {pixels.dtype}")
    rows = np.concatenate([np.zeros((h, 1), np.uint8), pixels.reshape(h, w * 3)], axis=1)
    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)  # 8-bit truecolour
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 6))
        + _chunk(b"IEND", b"")
    )


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> Path:
    """Write a tau-tonemapped 8-bit PNG preview of a (3, H, W) linear image, atomically."""
    path = Path(path)
    data = encode_png(to_uint8(rgb))
    write_bytes_atomic(path, data)
    return path
