"""EXR files the reader refuses from the header, before any pixel is decoded: frames above
the pixel limit, deep parts, tiled multi-level parts; and a MemoryError during a run as one
line naming the file and the frame size (issue 27, items 2 and 3)."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest
from test_cli_reliability import one_error_line
from test_cli_run import H, W, invoke, make_sequence, temp_files

from rtdenoise.runtime import InputError
from rtdenoise.runtime.sequences import exr as exr_module
from rtdenoise.runtime.sequences import run as run_module
from rtdenoise.runtime.sequences.exr import (
    DEFAULT_MAX_PIXELS,
    pixel_limit,
    read_exr,
    read_exr_header,
    write_exr,
)
from rtdenoise.runtime.sequences.frames import plan_sequence

CANONICAL = ["R", "G", "B", "albedo.R", "albedo.G", "albedo.B", "depth.Z"]


def write_deep(path, names=CANONICAL, h=H, w=W):
    """A deep scanline file: two samples per pixel in every channel."""
    px = np.empty((h, w), dtype=object)
    for i in range(h):
        for j in range(w):
            px[i, j] = np.full(2, 0.5, np.float32)
    header = {"compression": OpenEXR.ZIPS_COMPRESSION, "type": OpenEXR.deepscanline}
    with OpenEXR.File(header, {n: px for n in names}) as f:
        f.write(str(path))


def write_mipmap(path, names=CANONICAL, h=H, w=W):
    tiles = OpenEXR.TileDescription()
    tiles.xSize, tiles.ySize, tiles.mode = 8, 8, OpenEXR.MIPMAP_LEVELS
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.tiledimage, "tiles": tiles}
    with OpenEXR.File(header, {n: np.ones((h, w), np.float32) for n in names}) as f:
        f.write(str(path))


def test_default_limit_is_8k_by_8k():
    assert DEFAULT_MAX_PIXELS == 8192 * 8192
    assert exr_module.current_pixel_limit() == DEFAULT_MAX_PIXELS


def test_frame_above_the_limit_is_refused_from_the_header(tmp_path, monkeypatch):
    path = tmp_path / "big.exr"
    write_exr(path, {"R": np.zeros((40, 50), np.float32)})
    decoded = []
    monkeypatch.setattr(exr_module, "_decode", lambda *a: decoded.append(a) or {})
    for read in (
        lambda: read_exr(path, max_pixels=1999),
        lambda: read_exr_header(path, max_pixels=1999),
    ):
        with pytest.raises(InputError, match=r"big\.exr: part 0 is 50x40 \(2000 pixels\), above"):
            read()
    with pixel_limit(1999), pytest.raises(InputError, match="above the pixel limit of 1999"):
        read_exr(path)
    assert decoded == []  # refused before any decode
    assert read_exr_header(path, max_pixels=2000) == {"R": (40, 50)}


def test_default_limit_refuses_a_small_file_of_a_huge_frame(tmp_path):
    """8200 x 8200 zeros: a 4 MB file that decodes to 134 MB per half channel."""
    path = tmp_path / "huge.exr"
    write_exr(path, {"R": np.zeros((8200, 8200), np.float16)})
    assert path.stat().st_size < 8 << 20
    with pytest.raises(InputError, match=r"huge\.exr: part 0 is 8200x8200 \(67240000 pixels\)"):
        read_exr(path)


@pytest.mark.parametrize(
    ("write", "match"),
    [
        (write_deep, r"f\.exr: part 0 is a deep EXR \(deepscanline"),
        (write_mipmap, r"f\.exr: part 0 is a tiled multi-level EXR \(MIPMAP_LEVELS\)"),
    ],
)
def test_deep_and_multi_level_files_are_refused_at_the_header(tmp_path, write, match):
    write(tmp_path / "f.exr")
    for read in (read_exr_header, read_exr):
        with pytest.raises(InputError, match=match):
            read(tmp_path / "f.exr")
    with pytest.raises(InputError, match=match):
        plan_sequence([tmp_path / "f.exr"])


@pytest.mark.parametrize("write", [write_deep, write_mipmap])
def test_denoise_run_refuses_a_deep_or_mipmap_frame_before_writing(tmp_path, write):
    """A deep frame 2 used to pass the header check and crash when reached (TypeError, exit
    1, frame 1 written)."""
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=3, refs=False)
    write(seq / "frame_0002.exr")
    line = one_error_line(invoke(seq, "-o", out))
    assert "frame_0002.exr: part 0 is a" in line
    assert not out.exists() or list(out.iterdir()) == []


def test_denoise_run_max_pixels(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2, refs=False)
    line = one_error_line(invoke(seq, "-o", out, "--max-pixels", H * W - 1))
    assert f"frame_0001.exr: part 0 is {W}x{H} ({H * W} pixels), above the pixel limit" in line
    assert not out.exists() or list(out.iterdir()) == []
    assert invoke(seq, "-o", out, "--max-pixels", H * W).exit_code == 0


def test_memory_error_in_a_run_is_one_line_naming_the_frame(tmp_path, monkeypatch):
    """A MemoryError used to reach the user as a traceback (exit 1)."""
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=3, refs=False)
    real, calls = run_module.quantize_output, []

    def quantize(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise MemoryError
        return real(*args, **kwargs)

    monkeypatch.setattr(run_module, "quantize_output", quantize)
    line = one_error_line(invoke(seq, "-o", out))
    assert f"frame_0002.exr: out of memory denoising its {W}x{H} frame" in line
    assert sorted(p.name for p in out.iterdir()) == ["frame_0001.exr"] and not temp_files(out)


def test_memory_error_while_decoding_names_the_file(tmp_path, monkeypatch):
    path = tmp_path / "f.exr"
    write_exr(path, {"R": np.zeros((4, 6), np.float32)})

    def no_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(exr_module.OpenEXR, "File", no_memory)
    monkeypatch.setattr(exr_module, "read_exr_header", lambda *a, **k: {"R": (4, 6)})
    with pytest.raises(InputError, match=r"f\.exr: out of memory decoding its 6x4 frame"):
        read_exr(path)
