"""A killed render resumes exactly: kept frames stay, the rest is rendered with the same seeds,
and the finished folder equals one rendered in one go (skips without mitsuba)."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from rtdenoise.runtime.sequences.exr import read_exr

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("mitsuba") is None, reason="mitsuba not installed ([data] extra)"
)


class Killed(Exception):
    """Stands in for SIGKILL in the middle of a sequence."""


def _render(folder, cfg, on_frame=None):
    from rtdenoise.datagen.render import render_sequence
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")
    return render_sequence(folder, 42, cfg, variant="scalar_rgb", on_frame=on_frame)


def _kill_after(frame: int):
    def on_frame(t):
        if t == frame:
            raise Killed

    return on_frame


def _files(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.fixture(scope="module")
def cfg():
    from rtdenoise.datagen.render import RenderConfig

    return RenderConfig(20, 16, 4, spp_ref=8, half=True, kinds=("texture",))


@pytest.fixture(scope="module")
def whole(tmp_path_factory, cfg):
    folder = tmp_path_factory.mktemp("whole")
    _render(folder, cfg)
    return folder


def test_a_killed_sequence_is_finished_not_kept_half(tmp_path, cfg, whole):
    with pytest.raises(Killed):
        _render(tmp_path, cfg, _kill_after(1))
    assert not (tmp_path / "meta.json").exists() and (tmp_path / "partial.json").exists()
    assert (tmp_path / "ref_0001.exr").exists() and not (tmp_path / "frame_0002.exr").exists()
    (tmp_path / "ref_0001.exr").unlink()  # killed between frame_0001 and ref_0001
    (tmp_path / ".frame_0002.abcd1234.tmp.exr").write_bytes(b"half a file")  # a killed write
    kept = {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*_0000.exr")}
    seen = []
    meta = _render(tmp_path, cfg, seen.append)
    assert meta["resumed_frames"] == [0] and seen == [0, 1, 2, 3]
    assert {p.name: p.stat().st_mtime_ns for p in tmp_path.glob("*_0000.exr")} == kept
    assert _files(tmp_path) == _files(whole)  # no partial.json, no temp file left
    for name in _files(whole):
        if name.endswith(".exr"):
            a, b = read_exr(whole / name), read_exr(tmp_path / name)
            assert a.keys() == b.keys()
            for k in a:
                np.testing.assert_array_equal(a[k], b[k], err_msg=f"{name} {k}")
    m_whole = json.loads((whole / "meta.json").read_text())
    assert {k: v for k, v in meta.items() if k != "resumed_frames"} == {
        k: v for k, v in m_whole.items() if k != "resumed_frames"
    }


def test_a_partial_folder_of_other_settings_is_rendered_again(tmp_path, cfg):
    from dataclasses import replace

    with pytest.raises(Killed):
        _render(tmp_path, cfg, _kill_after(1))
    meta = _render(tmp_path, replace(cfg, spp_ref=4))
    assert meta["resumed_frames"] == [] and meta["spp"]["ref"] == 4
    assert len(list(tmp_path.glob("frame_*.exr"))) == 4


def test_the_cli_finishes_a_killed_job(tmp_path):
    from typer.testing import CliRunner

    from rtdenoise.cli.render import app
    from rtdenoise.datagen.cluster import sequence_name
    from rtdenoise.datagen.render import RenderConfig, render_sequence
    from rtdenoise.datagen.seeds import derive_seed

    cfg = RenderConfig(16, 16, 3, spp_ref=4, kinds=("lights",))
    with pytest.raises(Killed):
        render_sequence(tmp_path / sequence_name(1), derive_seed(9, 1), cfg,
                        variant="scalar_rgb", on_frame=_kill_after(0),
                        meta_extra={"job": {"base_seed": 9, "index": 1}})  # fmt: skip
    args = f"{tmp_path} -n 2 -f 3 --size 16x16 --spp-ref 4 --seed 9 --kinds lights".split()
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    meta = json.loads((tmp_path / "seq_001" / "meta.json").read_text())
    assert meta["resumed_frames"] == [0] and meta["job"] == {"base_seed": 9, "index": 1}
    assert json.loads((tmp_path / "seq_000" / "meta.json").read_text())["resumed_frames"] == []


def test_two_processes_share_one_folder_without_clashing(tmp_path):
    import re
    import subprocess
    import sys

    args = [sys.executable, "-m", "rtdenoise.cli.render", str(tmp_path), "-n", "6", "-f", "2",
            "--size", "16x16", "--spp-ref", "4", "--seed", "3", "--kinds", "texture"]  # fmt: skip
    procs = [subprocess.Popen(args, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    logs = [p.communicate(timeout=300)[1] for p in procs]
    assert all(p.returncode == 0 for p in procs), logs
    rendered = [int(re.search(r"rendered (\d+) sequence", log).group(1)) for log in logs]
    assert sum(rendered) == 6, logs  # each sequence rendered by exactly one of them
    for i in range(6):
        seq = tmp_path / f"seq_{i:03d}"
        meta = json.loads((seq / "meta.json").read_text())
        assert meta["resumed_frames"] == [] and not (seq / ".lock").exists()
