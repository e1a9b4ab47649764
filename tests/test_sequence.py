"""Finding, ordering and reading EXR frame sequences and their references."""

from __future__ import annotations

import numpy as np
import pytest

import rtdenoise.runtime.sequences.frames as sequence
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import write_exr
from rtdenoise.runtime.sequences.frames import (
    find_frames,
    find_reference,
    frame_number,
    iter_sequence,
    match_references,
    plan_sequence,
    read_frame,
    read_reference,
    reference_index,
    scan_sequence,
)


def rgb_frame(path, value: float, h: int = 4, w: int = 5, extra: dict | None = None):
    ch = {c: np.full((h, w), value + i, np.float32) for i, c in enumerate("RGB")}
    return write_exr(path, ch | (extra or {}), half=False)


@pytest.fixture
def seq(tmp_path):
    """frame_1, frame_2, frame_10 (+ refs for 1 and 10, a temp file, a non-EXR file)."""
    for n in (10, 1, 2):
        rgb_frame(tmp_path / f"frame_{n:04d}.exr", n)
    rgb_frame(tmp_path / "ref_0001.exr", 100)
    rgb_frame(tmp_path / "ref_0010.exr", 110)
    (tmp_path / ".frame_0003.abc.tmp.exr").write_bytes(b"partial")
    (tmp_path / "notes.txt").write_text("x")
    return tmp_path


def test_frame_number():
    assert frame_number("a/shot2_frame_0012.exr") == 12
    assert frame_number("v3/render.exr") is None  # only the stem counts
    assert frame_number("x_7_beauty.exr") == 7


def test_folder_glob_printf_file_and_list(seq):
    names = ["frame_0001.exr", "frame_0002.exr", "frame_0010.exr"]  # numeric, not lexical order
    assert [p.name for p in find_frames(seq)] == names
    assert [p.name for p in find_frames(str(seq / "*.exr"))] == names  # ref_* skipped
    assert [p.name for p in find_frames(str(seq / "ref_*.exr"))] == ["ref_0001.exr", "ref_0010.exr"]
    assert [p.name for p in find_frames(str(seq / "frame_%04d.exr"))] == names
    with pytest.raises(InputError, match=r"frame_%d\.exr: no EXR frames found"):
        find_frames(str(seq / "frame_%d.exr"))  # %d matches frame_1.exr, not frame_0001.exr
    assert find_frames(seq / "frame_0002.exr") == [seq / "frame_0002.exr"]
    two = find_frames([seq / "frame_0010.exr", str(seq / "frame_000[12].exr")])
    assert [p.name for p in two] == names


def test_find_errors(tmp_path, seq):
    with pytest.raises(InputError, match="nothing_here: no such file or folder"):
        find_frames(tmp_path / "nothing_here")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty: no EXR frames found"):
        find_frames(tmp_path / "empty")
    rgb_frame(seq / "frame_2.exr", 0)
    with pytest.raises(InputError, match="two frames with frame number 2"):
        find_frames(seq)
    with pytest.raises(InputError, match="exactly one %d"):
        find_frames(str(seq / "f_%d_%d.exr"))


def test_references(seq, tmp_path):
    frames = find_frames(seq)
    assert find_reference(frames[0]) == seq / "ref_0001.exr"
    assert find_reference(frames[1]) is None
    assert match_references(frames) == [seq / "ref_0001.exr", None, seq / "ref_0010.exr"]
    pad = tmp_path / "pad"
    pad.mkdir()
    rgb_frame(pad / "f_01.exr", 0)
    rgb_frame(pad / "ref_1.exr", 0)  # other zero padding: matched by number
    assert match_references([pad / "f_01.exr"]) == [pad / "ref_1.exr"]
    assert find_reference(pad / "f_01.exr") == pad / "ref_1.exr"
    other = tmp_path / "refs"
    other.mkdir()
    rgb_frame(other / "gt_2.exr", 5)  # a folder without ref_* files: all EXRs are references
    assert match_references(frames, other) == [None, other / "gt_2.exr", None]
    assert reference_index(str(seq / "ref_%04d.exr")) == {
        1: seq / "ref_0001.exr",
        10: seq / "ref_0010.exr",
    }
    np.testing.assert_array_equal(read_reference(seq / "ref_0010.exr")[:, 0, 0], [110, 111, 112])
    with pytest.raises(InputError, match=r"ref_0010\.exr: frame is 5x4 but the sequence is 4x4"):
        read_reference(seq / "ref_0010.exr", expect_size=(4, 4))


def test_nonfinite_counted_and_replaced(tmp_path):
    color = np.ones((3, 4, 5), np.float32)
    color[0, 0, 0] = np.nan
    color[2, 0, 0] = np.inf  # same pixel: counted once
    color[1, 3, 4] = -np.inf
    albedo = np.full((4, 5), 0.5, np.float32)
    albedo[2, 2] = np.nan
    ch = {c: color[i] for i, c in enumerate("RGB")} | {f"albedo.{c}": albedo for c in "RGB"}
    frame = read_frame(write_exr(tmp_path / "f_1.exr", ch, half=False))
    assert frame.nonfinite == 3 and frame.nonfinite_buffers == ("color", "albedo")
    assert all(np.isfinite(b).all() for b in frame.buffers.values())
    assert frame.buffers["color"][0, 0, 0] == 0 and frame.buffers["color"][1, 0, 0] == 1
    assert frame.buffers["albedo"][1, 2, 2] == 0


def test_iter_sequence_and_size_mismatch(seq):
    frames = list(iter_sequence(seq))
    assert [f.index for f in frames] == [1, 2, 10]
    np.testing.assert_array_equal(frames[2].buffers["color"][:, 0, 0], [10, 11, 12])
    rgb_frame(seq / "frame_0005.exr", 5, h=6)
    with pytest.raises(
        InputError, match=r"frame_0005\.exr: frame is 5x6 but .*frame_0001\.exr is 5x4"
    ):
        scan_sequence(find_frames(seq))
    with pytest.raises(InputError, match=r"frame_0005\.exr: frame is 5x6 but the sequence is 5x4"):
        read_frame(seq / "frame_0005.exr", expect_size=(4, 5))


def test_scan_reports_missing_channel_before_reading(seq):
    write_exr(seq / "frame_0003.exr", {"R": np.zeros((4, 5)), "G": np.zeros((4, 5))})
    with pytest.raises(InputError, match=r"frame_0003\.exr: missing channel B .*present: G, R"):
        scan_sequence(find_frames(seq))


def canonical_frame(path, value: float, h: int = 4, w: int = 5, **layers):
    """R,G,B plus layers given as name=(components, (h, w) or None for the frame's size);
    a layer of another size goes into a part of its own (multi-part file)."""
    import OpenEXR

    parts: dict[tuple[int, int], dict[str, np.ndarray]] = {(h, w): {}}
    parts[(h, w)] |= {c: np.full((h, w), value + i, np.float32) for i, c in enumerate("RGB")}
    for layer, (comps, size) in layers.items():
        size = size or (h, w)
        parts.setdefault(size, {}).update(
            {f"{layer}.{c}": np.full(size, value, np.float32) for c in comps}
        )

    def window(hh: int, ww: int) -> tuple[np.ndarray, np.ndarray]:
        return np.array([0, 0], np.int32), np.array([ww - 1, hh - 1], np.int32)

    headers = [
        {
            "compression": OpenEXR.ZIP_COMPRESSION,
            "type": OpenEXR.scanlineimage,
            "displayWindow": window(h, w),  # one per file, every part the same
            "dataWindow": window(*size),
        }
        for size in parts
    ]
    OpenEXR.File(
        [
            OpenEXR.Part(hdr, ch, name=f"p{i}")
            for i, (hdr, ch) in enumerate(zip(headers, parts.values(), strict=True))
        ]
    ).write(str(path))
    return path


def _spy(monkeypatch, name):
    """Record the calls of sequence.<name> (args, kwargs), still calling it."""
    calls = []
    real = getattr(sequence, name)

    def spy(*args, **kwargs):
        calls.append((args, kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(sequence, name, spy)
    return calls


def test_plan_resolves_once_and_reads_only_the_planned_channels(tmp_path, monkeypatch):
    for n in range(1, 5):
        canonical_frame(
            tmp_path / f"f_{n}.exr",
            n,
            albedo=("RGB", None),
            normal=("XYZ", None),
            depth=("Z", None),
        )
    paths = find_frames(tmp_path)
    resolves = _spy(monkeypatch, "resolve_channels")
    reads = _spy(monkeypatch, "read_exr")
    plan = plan_sequence(paths, buffers=("color", "depth"))
    assert len(resolves) == 1 and reads == []  # headers only, one resolve for 4 frames
    assert plan.channels == {"color": ("R", "G", "B"), "depth": ("depth.Z",)}
    frames = [plan.read(p, index=i) for i, p in enumerate(paths)]
    assert len(resolves) == 1  # reading reuses the mapping
    assert [a[1] for a, _ in reads] == [["R", "G", "B", "depth.Z"]] * 4  # nothing else read
    assert all(set(f.buffers) == {"color", "depth"} for f in frames)
    assert all(b.dtype == np.float32 for f in frames for b in f.buffers.values())
    np.testing.assert_array_equal(frames[3].buffers["depth"], np.full((1, 4, 5), 4.0))
    assert plan_sequence(paths).channels.keys() == {"color", "albedo", "normal", "depth"}


def test_unused_layers_are_not_checked_needed_ones_are(tmp_path):
    canonical_frame(tmp_path / "f_1.exr", 1, albedo=("RGB", None), junk=("RGB", None))
    canonical_frame(tmp_path / "f_2.exr", 2, albedo=("RGB", (6, 5)), junk=("RG", None))
    canonical_frame(tmp_path / "f_3.exr", 3)  # no albedo at all
    paths = find_frames(tmp_path)
    plan = plan_sequence(paths, buffers=("color",))  # albedo unused: odd sizes do not matter
    assert plan.size == (4, 5) and set(plan.read(paths[2]).buffers) == {"color"}
    with pytest.raises(InputError, match=r"f_2\.exr: channel 'albedo\.R' is 5x6 but channel 'R'"):
        plan_sequence(paths, buffers=("color", "albedo"))
    with pytest.raises(
        InputError, match=r"f_3\.exr: missing channel albedo\.R, albedo\.G, albedo\.B for buffer"
    ):
        plan_sequence(paths[::2], buffers=("albedo",))
    with pytest.raises(InputError, match=r"f_3\.exr: .*buffer 'albedo'.*present: B, G, R"):
        plan_sequence(paths[2:], buffers=("albedo",))  # the first frame lacks it
    with pytest.raises(InputError, match=r"f_1\.exr: the model needs buffer 'albedo', which"):
        plan_sequence(paths, overrides={"albedo": "none"}, buffers=("albedo",))
    with pytest.raises(InputError, match=r"f_1\.exr: the model needs buffer 'color_b', for which"):
        plan_sequence(paths, "blender", buffers=("color_b",))


def test_mapping_comes_from_the_first_frame(tmp_path):
    """Every frame must hold the first frame's channels, even where a per-file resolve would
    have found the buffer elsewhere (one layout per sequence)."""
    canonical_frame(tmp_path / "f_1.exr", 1, normal=("XYZ", None))
    canonical_frame(tmp_path / "f_2.exr", 2, normal=("RGB", None))
    paths = find_frames(tmp_path)
    assert read_frame(paths[1]).buffers.keys() == {"color", "normal"}
    with pytest.raises(InputError, match=r"f_2\.exr: missing channel normal\.X, normal\.Y"):
        plan_sequence(paths, buffers=("normal",))


def test_read_frame_buffers_subset(tmp_path):
    path = canonical_frame(tmp_path / "f_7.exr", 7, albedo=("RGB", (2, 2)), depth=("Z", None))
    frame = read_frame(path, buffers=("depth",))  # the odd-sized albedo is not read
    assert frame.index == 7 and set(frame.buffers) == {"color", "depth"}
    with pytest.raises(InputError, match=r"f_7\.exr: channel 'albedo\.R' is 2x2 but channel 'R'"):
        read_frame(path)  # every buffer: the albedo counts
