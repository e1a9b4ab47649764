"""EXR frame reading/writing and PNG previews."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr, read_exr_header, write_exr
from rtdenoise.runtime.sequences.frames import (
    as_written,
    quantize_output,
    read_frame,
    read_reference,
    write_output,
)
from rtdenoise.runtime.sequences.preview import encode_png, to_uint8, write_png

H, W = 48, 64


def canonical_channels(rng: np.random.Generator, h: int = H, w: int = W) -> dict[str, np.ndarray]:
    """All canonical channels (docs/contract.md, "EXR layout") with random values."""
    names = ["R", "G", "B"] + [f"colorB.{c}" for c in "RGB"] + [f"albedo.{c}" for c in "RGB"]
    names += [f"normal.{c}" for c in "XYZ"] + ["depth.Z", "motion.X", "motion.Y"]
    return {n: rng.random((h, w), dtype=np.float32) * 4 - 1 for n in names}


def test_canonical_frame_round_trip(tmp_path):
    ch = canonical_channels(np.random.default_rng(0))
    path = write_exr(tmp_path / "frame_0007.exr", ch, half=False)
    frame = read_frame(path)
    assert frame.index == 7 and frame.path == path and frame.nonfinite == 0
    shapes = {k: v.shape for k, v in frame.buffers.items()}
    assert shapes == {
        "color": (3, H, W),
        "color_b": (3, H, W),
        "albedo": (3, H, W),
        "normal": (3, H, W),
        "depth": (1, H, W),
        "motion": (2, H, W),
    }
    assert all(v.dtype == np.float32 for v in frame.buffers.values())
    np.testing.assert_array_equal(frame.buffers["color"][1], ch["G"])
    np.testing.assert_array_equal(frame.buffers["normal"][2], ch["normal.Z"])
    np.testing.assert_array_equal(frame.buffers["motion"][1], ch["motion.Y"])  # no conversion
    np.testing.assert_array_equal(frame.buffers["depth"][0], ch["depth.Z"])
    assert frame.size == (H, W)


def test_optional_buffers_absent(tmp_path):
    rng = np.random.default_rng(1)
    path = write_exr(tmp_path / "f_1.exr", {c: rng.random((8, 9), np.float32) for c in "RGB"})
    assert set(read_frame(path).buffers) == {"color"}


def test_write_output_half_and_float(tmp_path):
    rgb = (np.random.default_rng(2).random((3, H, W)) * 100).astype(np.float32)
    write_output(tmp_path / "h.exr", rgb)
    write_output(tmp_path / "f.exr", rgb, half=False)
    half = read_exr(tmp_path / "h.exr")
    assert sorted(half) == ["B", "G", "R"]
    np.testing.assert_array_equal(half["R"], rgb[0].astype(np.float16).astype(np.float32))
    np.testing.assert_array_equal(read_exr(tmp_path / "f.exr")["B"], rgb[2])
    np.testing.assert_array_equal(read_reference(tmp_path / "f.exr"), rgb)
    hot = np.full((3, 2, 2), 1e6, np.float32)  # beyond half range: clamped, not Inf
    write_output(tmp_path / "hot.exr", hot)
    np.testing.assert_array_equal(read_exr(tmp_path / "hot.exr")["G"], np.full((2, 2), 65504.0))
    with pytest.raises(ValueError, match=r"\(3, H, W\)"):
        write_output(tmp_path / "bad.exr", rgb[:2])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.exr", "h.exr", "hot.exr"]  # no temps


def test_header_sizes_and_corrupt_files(tmp_path):
    path = write_exr(tmp_path / "a.exr", {"R": np.zeros((5, 7)), "x.Z": np.ones((5, 7))})
    assert read_exr_header(path) == {"R": (5, 7), "x.Z": (5, 7)}
    data = path.read_bytes()
    (tmp_path / "trunc.exr").write_bytes(data[: len(data) // 2])
    (tmp_path / "junk.exr").write_bytes(b"not an exr file at all" * 10)
    for name in ("trunc.exr", "junk.exr"):
        with pytest.raises(InputError, match=name + ": cannot read EXR"):
            read_exr(tmp_path / name)
    with pytest.raises(InputError, match="junk.exr: cannot read EXR"):
        read_exr_header(tmp_path / "junk.exr")


def _decode_png(data: bytes) -> tuple[int, int, np.ndarray]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, size = 8, b"", None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])
        assert crc == zlib.crc32(kind + body)
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (8, 2)
            size = (h, w)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    h, w = size
    rows = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 3 * w)
    assert not rows[:, 0].any()  # filter type 0
    return h, w, rows[:, 1:].reshape(h, w, 3)


def test_png_preview_values(tmp_path):
    # tau(1) = 0.5^(1/2.4) = 0.74915 -> 191; tau(0) = 0; tau(-3) = 0 (clamped); tau(Inf) = 1 -> 255
    # tau(0.1) = (1/11)^(1/2.4) = 0.36852 -> 94
    rgb = np.array(
        [[[1.0, 0.0, 0.1]], [[-3.0, np.inf, 1.0]], [[0.1, 1.0, np.nan]]], dtype=np.float32
    )  # (3, 1, 3)
    expected = np.array([[[191, 0, 94], [0, 255, 191], [94, 191, 0]]], dtype=np.uint8)
    np.testing.assert_array_equal(to_uint8(rgb), expected)
    path = write_png(tmp_path / "p.png", rgb)
    h, w, pixels = _decode_png(path.read_bytes())
    assert (h, w) == (1, 3)
    np.testing.assert_array_equal(pixels, expected)
    assert _decode_png(encode_png(np.zeros((4, 5, 3), np.uint8)))[:2] == (4, 5)
    assert [p.name for p in tmp_path.iterdir()] == ["p.png"]


def _three_part_file(path, seed: int):
    """A multi-part EXR with parts VL.P0..VL.P2, channels R,G,B each (32 x 32)."""
    import OpenEXR

    rng = np.random.default_rng(seed)
    parts = [
        OpenEXR.Part(
            {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
            {f"VL.P{i}.{c}": rng.random((32, 32), dtype=np.float32) for c in "RGB"},
            name=f"VL.P{i}",
        )
        for i in range(3)
    ]
    OpenEXR.File(parts).write(str(path))
    return path


def _truncate(path, keep: float = 0.8) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])  # the last part loses its pixels


def test_truncated_multipart_is_an_error(tmp_path):
    # OpenEXR 3.5 silently drops the parts it cannot read; read_exr must not.
    path = _three_part_file(tmp_path / "m.exr", 4)
    assert len(read_exr(path)) == 9
    _truncate(path)
    with pytest.raises(InputError, match=r"m\.exr: cannot read EXR \(truncated or corrupt"):
        read_exr(path)


def test_read_exr_subset_converts_only_the_channels_asked_for(tmp_path):
    rng = np.random.default_rng(5)
    ch = canonical_channels(rng)
    path = write_exr(tmp_path / "h.exr", ch)  # half floats
    got = read_exr(path, ["G", "depth.Z"])
    assert list(got) == ["G", "depth.Z"] and all(a.dtype == np.float32 for a in got.values())
    np.testing.assert_array_equal(got["G"], ch["G"].astype(np.float16).astype(np.float32))
    raw = read_exr(path, ["R"], dtype=None)  # the file's own type, for converting while stacking
    assert raw["R"].dtype == np.float16 and raw["R"].flags.c_contiguous
    with pytest.raises(InputError, match=r"h\.exr: no channel 'albedo\.A'; channels present: B, G"):
        read_exr(path, ["R", "albedo.A"])


def test_subset_of_a_truncated_multipart_file(tmp_path):
    """A part dropped by OpenEXR is an error when a channel asked for was in it."""
    path = _three_part_file(tmp_path / "m.exr", 6)
    _truncate(path)
    with pytest.raises(InputError, match=r"m\.exr: cannot read EXR \(truncated .* 'VL\.P2\.G'"):
        read_exr(path, ["VL.P0.R", "VL.P2.G"])


def test_quantize_once_half_and_float(tmp_path):
    rgb = np.random.default_rng(7).normal(0, 3e4, (3, 8, 9)).astype(np.float32)
    rgb[0, 0, 0], rgb[1, 0, 0] = 1e6, -1e6
    q = quantize_output(rgb)
    assert q.dtype == np.float16 and q.flags.c_contiguous and np.isfinite(q).all()
    assert (q[0, 0, 0], q[1, 0, 0]) == (65504, -65504)
    np.testing.assert_array_equal(q, np.clip(rgb, -65504, 65504).astype(np.float16))
    np.testing.assert_array_equal(as_written(rgb), q.astype(np.float32))
    assert quantize_output(rgb, half=False) is rgb  # float32 contiguous: no copy
    write_output(tmp_path / "o.exr", rgb)
    ch = read_exr(tmp_path / "o.exr", dtype=None)
    assert ch["R"].dtype == np.float16
    np.testing.assert_array_equal(np.stack([ch[c] for c in "RGB"]), q)
