"""Outputs record what made them, and --resume refuses to mix (issue 28): model (path and
sha256 of the .onnx), the options that change the pixels and the rtdenoise version in every
output's EXR header (runtime/sequences/provenance.py)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
from test_bad_input import make_files
from test_cli_run import invoke, make_sequence, rgb

from rtdenoise import __version__
from rtdenoise.runtime import resolve_model
from rtdenoise.runtime.sequences.exr import read_exr_attributes, write_exr
from rtdenoise.runtime.sequences.layouts import get_layout
from rtdenoise.runtime.sequences.provenance import file_sha256, mismatch, options_of, record


def error_line(res) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error: "), res.output
    return lines[0]


def test_outputs_record_model_options_and_version(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    make_files(seq, range(1, 3), refs=False)
    res = invoke(seq, "-o", out, "--model", "demo:wskp", "--threads", "1", "--float")
    assert res.exit_code == 0, res.output
    model = resolve_model("demo:wskp")
    for k in (1, 2):
        attrs = read_exr_attributes(out / f"frame_{k:04d}.exr", "rtdenoise.")
        assert attrs["rtdenoise.model"] == str(model)
        assert attrs["rtdenoise.model_sha256"] == file_sha256(model)
        assert attrs["rtdenoise.version"] == __version__
        options = json.loads(attrs["rtdenoise.options"])
        assert options == {"layout": "canonical", "channels": {}, "half": False}


def test_resume_refuses_another_model_or_other_options_naming_which(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    make_files(seq, range(1, 4))
    assert invoke(seq, "-o", out).exit_code == 0  # --model none
    (out / "frame_0003.exr").unlink()
    kept = {p.name: p.read_bytes() for p in out.iterdir()}
    first = out / "frame_0001.exr"
    line = error_line(invoke(seq, "-o", out, "--resume", "--model", "demo:wskp"))
    assert line.startswith(f"error: {first}: --resume would mix outputs: model differs: none")
    assert "wskp.onnx (sha256 " in line and "--overwrite" in line
    line = error_line(invoke(seq, "-o", out, "--resume", "--float"))
    assert "options differ: half true there, false now" in line
    line = error_line(invoke(seq, "-o", out, "--resume", "--channel", "albedo=none"))
    assert 'options differ: channels {} there, {"albedo": "none"} now' in line
    mine = tmp_path / "mine.toml"  # the canonical preset's content under another name
    mine.write_text(get_layout("canonical").path.read_text())
    line = error_line(invoke(seq, "-o", out, "--resume", "--layout", mine))
    assert f'layout "canonical" there, "mine:{file_sha256(mine)}" now' in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == kept  # nothing touched
    res = invoke(seq, "-o", out, "--resume")  # the same model and options: continues
    assert res.exit_code == 0, res.output
    assert (out / "frame_0003.exr").is_file()


def test_resume_refuses_an_output_that_records_nothing(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    out.mkdir()
    colors, _ = make_sequence(seq, n=2)
    write_exr(out / "frame_0001.exr", {c: colors[0][i] for i, c in enumerate("RGB")})
    line = error_line(invoke(seq, "-o", out, "--resume"))
    assert f"{out / 'frame_0001.exr'}: --resume would mix outputs: it records no model" in line
    assert invoke(seq, "-o", out, "--overwrite").exit_code == 0
    np.testing.assert_allclose(rgb(out / "frame_0001.exr"), colors[0], rtol=2**-10)


def test_online_learning_and_run_time_options_are_options():
    backend = SimpleNamespace(
        source=None, name="x", options={"kernel_size": 13}, online={"step": "s"},
        learn=True, learn_every=4, relearn_at_cuts=False,
    )  # fmt: skip
    layout = get_layout("canonical")
    options = options_of(backend, layout, {}, True)
    assert options["model_options"] == {"kernel_size": 13.0}
    online = (options["learn"], options["learn_every"], options["relearn_at_cuts"])
    assert online == (True, 4, False)
    before = record(backend, layout, {}, True)
    backend.learn_every = 1
    assert mismatch(before, record(backend, layout, {}, True)) == (
        "options differ: learn_every 4 there, 1 now"
    )
    assert mismatch(before, before) is None
    newer = {**before, "rtdenoise.version": "9.0.0"}  # recorded, not compared
    assert mismatch(newer, before) is None
