"""Durable outputs: fsync of the temp file before the rename and of the folder after; and
`--resume` redoes a kept output that does not read (issue 27, item 5)."""

from __future__ import annotations

import os

import numpy as np
from test_bad_input import make_files
from test_cli_run import invoke, rgb, temp_files

from rtdenoise.runtime.sequences import atomic
from rtdenoise.runtime.sequences.exr import write_exr


def test_file_then_folder_are_fsynced_around_the_rename(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.path.isdir(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(a, b):
        events.append(("replace", os.path.getsize(a) > 0))
        real_replace(a, b)

    monkeypatch.setattr(atomic.os, "fsync", fsync)
    monkeypatch.setattr(atomic.os, "replace", replace)
    write_exr(tmp_path / "f.exr", {"R": np.ones((4, 4), np.float32)})
    assert events == [("fsync", False), ("replace", True), ("fsync", True)]


def test_fsync_folder_tolerates_a_file_system_that_refuses(tmp_path, monkeypatch):
    def refuse(fd):
        raise OSError(22, "Invalid argument")

    monkeypatch.setattr(atomic.os, "fsync", refuse)
    atomic.fsync_folder(tmp_path)  # no error


def test_resume_redoes_empty_truncated_and_wrong_size_outputs(tmp_path):
    """A renamed file whose data never reached the disk (empty), a truncated one and one of
    another size used to be kept by --resume."""
    seq = tmp_path / "seq"
    make_files(seq, range(1, 6), refs=False)
    full, part = tmp_path / "full", tmp_path / "part"
    args = ["--model", "demo:wskp", "--threads", "1", "--float"]
    assert invoke(seq, "-o", full, *args).exit_code == 0
    assert invoke(seq, "-o", part, *args).exit_code == 0
    (part / "frame_0002.exr").write_bytes(b"")
    data = (part / "frame_0003.exr").read_bytes()
    (part / "frame_0003.exr").write_bytes(data[: len(data) // 2])
    write_exr(part / "frame_0004.exr", {c: np.zeros((3, 5), np.float32) for c in "RGB"})
    kept = {k: (part / f"frame_{k:04d}.exr").stat().st_mtime_ns for k in (1, 5)}
    res = invoke(seq, "-o", part, "--resume", *args)
    assert res.exit_code == 0, res.output
    for k in (2, 3, 4):
        assert f"frame_{k:04d}.exr: kept output does not read" in res.stderr
    assert "is 5x3, the sequence is" in res.stderr
    for k in range(1, 6):
        np.testing.assert_array_equal(
            rgb(part / f"frame_{k:04d}.exr"), rgb(full / f"frame_{k:04d}.exr")
        )
    assert {k: (part / f"frame_{k:04d}.exr").stat().st_mtime_ns for k in (1, 5)} == kept
    assert not temp_files(part)
