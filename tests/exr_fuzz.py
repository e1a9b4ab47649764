"""Hypothesis strategies and the property of the EXR reader fuzz (tests/test_exr_fuzz.py, and
longer in benchmarks/fuzz_exr.py): whatever the header fields, channel types, windows,
values and byte damage, `read_exr_header` / `read_exr` / `read_frame` either return arrays of
the header's size or raise one InputError naming the file; never another exception."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
from hypothesis import strategies as st

from rtdenoise.runtime import InputError
from rtdenoise.runtime.sequences.exr import read_exr, read_exr_header
from rtdenoise.runtime.sequences.frames import read_frame

NAMES = ["R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "depth.Z", "N.X", "a b", "é"]
TYPES = [np.float16, np.float32, np.uint32]
VALUES = [np.nan, np.inf, -np.inf, 0.0, -1.0, 1e-30, 65504.0, 1e6, 3e38]
COMPRESSIONS = [
    OpenEXR.NO_COMPRESSION,
    OpenEXR.ZIP_COMPRESSION,
    OpenEXR.ZIPS_COMPRESSION,
    OpenEXR.PIZ_COMPRESSION,
    OpenEXR.RLE_COMPRESSION,
]


@st.composite
def exr_files(draw) -> dict:
    """The recipe of one file: size, windows, channels (name, type), values, damage."""
    h, w = draw(st.integers(1, 24)), draw(st.integers(1, 24))
    x0, y0 = draw(st.integers(-30, 30)), draw(st.integers(-30, 30))
    dx0, dy0 = draw(st.integers(-5, 5)), draw(st.integers(-5, 5))
    dw, dh = draw(st.integers(0, 40)), draw(st.integers(0, 40))
    names = draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=8, unique=True))
    return {
        "size": (h, w),
        "data": ((x0, y0), (x0 + w - 1, y0 + h - 1)),
        "display": ((dx0, dy0), (dx0 + dw, dy0 + dh)),
        "channels": {n: draw(st.sampled_from(TYPES)) for n in names},
        "values": draw(st.lists(st.sampled_from(VALUES), max_size=4)),
        "seed": draw(st.integers(0, 2**16)),
        "compression": draw(st.sampled_from(COMPRESSIONS)),
        "tiled": draw(st.booleans()),
        "truncate": draw(st.one_of(st.none(), st.floats(0.0, 1.0))),
        "flips": draw(st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(1, 255)), max_size=3)),
    }


def write_recipe(path: Path, r: dict) -> None:
    rng = np.random.default_rng(r["seed"])
    h, w = r["size"]
    data = {}
    for name, dtype in r["channels"].items():
        a = rng.exponential(1.0, (h, w)) * 4
        for v in r["values"]:
            a.flat[int(rng.integers(0, a.size))] = v
        if dtype is np.uint32:
            a = np.nan_to_num(a, nan=0, posinf=0, neginf=0).clip(0, 2**31)
        with np.errstate(all="ignore"):
            data[name] = np.ascontiguousarray(a.astype(dtype))
    header = {
        "compression": r["compression"],
        "type": OpenEXR.tiledimage if r["tiled"] else OpenEXR.scanlineimage,
        "dataWindow": r["data"],
        "displayWindow": r["display"],
    }
    if r["tiled"]:
        tiles = OpenEXR.TileDescription()
        tiles.xSize, tiles.ySize, tiles.mode = 8, 8, OpenEXR.ONE_LEVEL
        header["tiles"] = tiles
    with OpenEXR.File(header, data) as f:
        f.write(str(path))
    raw = bytearray(path.read_bytes())
    for where, xor in r["flips"]:
        raw[min(int(where * len(raw)), len(raw) - 1)] ^= xor
    if r["truncate"] is not None:
        raw = raw[: int(r["truncate"] * len(raw))]
    path.write_bytes(bytes(raw))


def check_recipe(r: dict, denoiser=None) -> None:
    """The property: only arrays of the header's size or one InputError naming the file; a
    frame that reads, given to `denoiser` (a Denoiser, optional), gives a finite,
    non-negative image of its size or an InputError."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "frame_0001.exr"
        write_recipe(path, r)
        damaged = bool(r["flips"]) or r["truncate"] is not None
        try:
            sizes = read_exr_header(path)
        except InputError as exc:
            assert str(path) in str(exc) and "\n" not in str(exc)
            return
        if not damaged:
            assert set(sizes) == set(r["channels"]) and set(sizes.values()) == {r["size"]}
        arrays: dict = {}
        for read in (lambda: read_exr(path), lambda: read_frame(path).buffers):
            arrays = {}
            try:
                arrays = read()
            except InputError as exc:
                assert str(path) in str(exc) and "\n" not in str(exc)
                continue
            for a in arrays.values():
                assert a.dtype == np.float32 and a.shape[-2:] == next(iter(sizes.values()))
        if denoiser is not None and "color" in arrays:
            try:
                out = denoiser.process(arrays)
            except InputError:
                return
            assert out.shape == arrays["color"].shape and np.isfinite(out).all()
            assert out.min() >= 0
