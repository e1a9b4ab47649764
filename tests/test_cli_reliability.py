"""denoise-run never overwrites by surprise, resumes exactly, fails early, cleans up."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from progress_lines import other_lines
from test_bad_input import make_files
from test_cli_run import invoke, make_sequence, rgb, temp_files

from rtdenoise.runtime.sequences.exr import read_exr, write_exr


def one_error_line(res) -> str:
    """The one error line (after the progress of frames done before it, if any)."""
    lines = other_lines(res.stderr)
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0]


def test_existing_outputs_are_never_overwritten_without_overwrite(tmp_path):
    """`-o` pointing at another shot's input folder used to replace its renders silently."""
    shot_a, shot_b = tmp_path / "a", tmp_path / "b"
    shot_a.mkdir()
    shot_b.mkdir()
    make_sequence(shot_a, n=2, seed=1)
    make_sequence(shot_b, n=2, seed=2)
    before = {p.name: p.read_bytes() for p in shot_b.iterdir()}
    line = one_error_line(invoke(shot_a, "-o", shot_b))
    assert f"{shot_b / 'frame_0001.exr'}: output exists (and 1 more)" in line
    assert "--overwrite" in line and "--resume" in line
    assert {p.name: p.read_bytes() for p in shot_b.iterdir()} == before
    assert "exclude each other" in one_error_line(invoke(shot_a, "-o", shot_b, "--overwrite",
                                                         "--resume"))  # fmt: skip
    res = invoke(shot_a, "-o", shot_b, "--overwrite")
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(
        rgb(shot_b / "frame_0001.exr"), rgb(shot_a / "frame_0001.exr"), rtol=2**-10, atol=1e-6
    )
    assert (shot_b / "ref_0001.exr").read_bytes() == before["ref_0001.exr"]  # not an output


def test_preview_counts_as_an_output(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=1)
    out.mkdir()
    (out / "frame_0001.png").write_bytes(b"mine")
    assert "frame_0001.png: output exists" in one_error_line(invoke(seq, "-o", out, "--preview"))
    assert invoke(seq, "-o", out).exit_code == 0  # no preview asked: the png is not in the way
    assert (out / "frame_0001.png").read_bytes() == b"mine"


def test_resume_denoises_the_missing_frames_exactly(tmp_path):
    """An interrupted run (outputs of frames 4-6 missing) resumed: the history is rebuilt from
    the frames before, so the outputs equal those of an uninterrupted run, bit for bit."""
    seq = tmp_path / "seq"
    make_files(seq, range(1, 7), refs=True)
    full, part = tmp_path / "full", tmp_path / "part"
    args = ["--model", "demo:wskp", "--threads", "1", "--float"]
    res = invoke(seq, "-o", full, "--metrics-json", tmp_path / "full.json", *args)
    assert res.exit_code == 0, res.output
    assert invoke(seq, "-o", part, *args).exit_code == 0
    kept = {k: (part / f"frame_{k:04d}.exr").stat().st_mtime_ns for k in (1, 2, 3)}
    for k in (4, 5, 6):
        (part / f"frame_{k:04d}.exr").unlink()
    res = invoke(seq, "-o", part, "--resume", "--metrics-json", tmp_path / "part.json", *args)
    assert res.exit_code == 0, res.output
    for k in range(1, 7):
        np.testing.assert_array_equal(
            rgb(part / f"frame_{k:04d}.exr"), rgb(full / f"frame_{k:04d}.exr")
        )
    assert {k: (part / f"frame_{k:04d}.exr").stat().st_mtime_ns for k in (1, 2, 3)} == kept
    a, b = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("full", "part"))
    assert [r["skipped"] for r in b["frames"]] == [True] * 3 + [False] * 3 and b["skipped"] == 3
    assert b["mean"] == pytest.approx(a["mean"]) and b["trmae"] == pytest.approx(a["trmae"])
    assert invoke(seq, "-o", part, "--resume", *args).exit_code == 0  # all done: nothing to do


def test_resume_rebuilds_at_most_16_frames_of_history(tmp_path, monkeypatch):
    from rtdenoise.runtime.sequences import run as run_module
    from rtdenoise.runtime.sequences.backend import PassThrough

    seq = tmp_path / "seq"
    seq.mkdir()
    make_sequence(seq, n=4)
    out = tmp_path / "out"
    assert invoke(seq, "-o", out).exit_code == 0
    (out / "frame_0004.exr").unlink()
    fed = []
    original = PassThrough.process

    def process(self, buffers, **kw):
        fed.append(buffers["color"].copy())
        return original(self, buffers, **kw)

    monkeypatch.setattr(PassThrough, "process", process)
    monkeypatch.setattr(run_module, "RESUME_WARMUP", 2)
    assert invoke(seq, "-o", out, "--resume").exit_code == 0
    assert len(fed) == 3  # frames 2 and 3 re-run (not 1), then frame 4


def test_metrics_json_that_cannot_be_written_fails_before_any_frame(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2)
    (tmp_path / "afile").write_text("x")
    line = one_error_line(invoke(seq, "-o", out, "--metrics-json", tmp_path / "afile" / "m.json"))
    assert "afile: is a file, not a folder" in line and not out.exists()
    if sys.platform.startswith("linux"):  # a folder nobody (root included) can create files in
        line = one_error_line(invoke(seq, "-o", out, "--metrics-json", "/proc/m.json"))
        assert "/proc/m.json: cannot write in /proc" in line and not out.exists()
    js = tmp_path / "new" / "sub" / "m.json"
    res = invoke(seq, "-o", out, "--metrics-json", js)
    assert res.exit_code == 0 and js.is_file()
    js.write_text("mine")  # an existing metrics file is an output like the others
    assert "m.json: exists; --overwrite" in one_error_line(
        invoke(seq, "-o", tmp_path / "o2", "--metrics-json", js)
    )
    assert js.read_text() == "mine" and not (tmp_path / "o2").exists()
    assert invoke(seq, "-o", out, "--metrics-json", js, "--overwrite").exit_code == 0
    assert json.loads(js.read_text())["frames"]


def test_temp_files_of_a_killed_run_are_removed(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2)
    out.mkdir()
    stale = out / ".frame_0002.k3j_x9q2.tmp.exr"  # what atomic_path names a temp file
    stale.write_bytes(b"half a frame")
    (out / ".keep").write_text("")  # not ours
    (out / ".frame_0002.notours.tmp.exr").write_text("")  # not a mkstemp name
    res = invoke(seq, "-o", out)
    assert res.exit_code == 0 and "removed 1 temp files an interrupted run left" in res.stderr
    assert not stale.exists() and (out / ".keep").exists()
    assert sorted(temp_files(out)) == [".frame_0002.notours.tmp.exr", ".keep"]


def test_nan_in_a_reference_leaves_that_frame_unscored(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=3)
    ch = read_exr(seq / "ref_0002.exr")
    ch["G"][5, 5] = np.nan
    write_exr(seq / "ref_0002.exr", ch)
    js = tmp_path / "m.json"
    res = invoke(seq, "-o", out, "--metrics-json", js)
    assert res.exit_code == 0
    assert "ref_0002.exr: 1 reference pixels are NaN/Inf: frame not scored" in res.stderr
    rows = json.loads(js.read_text())["frames"]
    assert [r["psnr"] is None for r in rows] == [False, True, False]
    assert rows[1]["reference_nonfinite"] == 1 and rows[1]["input"] is None
