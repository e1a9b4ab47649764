"""Finding, ordering and reading EXR frame sequences and their references."""

from __future__ import annotations

import numpy as np
import pytest

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.exr import write_exr
from rtdenoise.runtime.sequence import (
    find_frames,
    find_reference,
    frame_number,
    iter_sequence,
    match_references,
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
