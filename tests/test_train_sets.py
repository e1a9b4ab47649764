"""Training from rendered sets: a set folder stands for its complete sequences, and
--oversample draws a scene kind N times as often."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from train_data import write_sequence
from typer.testing import CliRunner

from rtdenoise.cli.train import app
from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.data import load_sequences, oversampled, sequence_kind, training_folders
from rtdenoise.runtime.errors import InputError


def _rendered(folder: Path, kind: str | None, seed: int) -> Path:
    """A sequence as denoise-render leaves it: complete with meta.json, or (kind None) still
    rendering, with partial.json only."""
    write_sequence(folder, frames=3, size=16, seed=seed)
    if kind is None:
        (folder / "partial.json").write_text("{}")
    else:
        (folder / "meta.json").write_text(json.dumps({"kind": kind, "cuts": []}))
    return folder


@pytest.fixture(scope="module")
def render_set(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("train_v2")
    _rendered(root / "seq_000", "glass", 0)
    _rendered(root / "seq_001", "lights", 1)
    _rendered(root / "seq_002", None, 2)  # killed mid-render
    _rendered(root / "seq_003", "room", 3)
    (root / "render.log").write_text("log\n")
    return root


def test_a_set_folder_stands_for_its_complete_sequences(render_set, tmp_path):
    single = write_sequence(tmp_path / "mine", frames=3, size=16, seed=9)
    folders, incomplete = training_folders([render_set, single])
    assert [f.name for f in folders] == ["seq_000", "seq_001", "seq_003", "mine"]
    assert incomplete == [render_set / "seq_002"]
    assert sequence_kind(folders[1]) == "lights" and sequence_kind(single) is None
    with pytest.raises(InputError, match="nowhere: no such sequence folder"):
        training_folders([tmp_path / "nowhere"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="empty: neither a sequence"):
        training_folders([tmp_path / "empty"])


def test_oversampling_repeats_a_kind_and_reads_it_once(render_set):
    folders, _ = training_folders([render_set])
    drawn = oversampled(folders, {"lights": 3})
    assert [f.name for f in drawn] == ["seq_000", "seq_001", "seq_001", "seq_001", "seq_003"]
    assert oversampled(folders, {}) == folders
    with pytest.raises(InputError, match=r"'water'.*present: glass, lights, room"):
        oversampled(folders, {"water": 2})
    seqs = load_sequences(drawn, ("color", "albedo"))
    assert len(seqs) == 5 and seqs[1] is seqs[2] is seqs[3] and seqs[0] is not seqs[4]
    assert seqs[1].name == "seq_001"


def test_cli_trains_on_a_set_with_a_kind_oversampled(render_set, tmp_path):
    runner = CliRunner()
    out = tmp_path / "set.pt"
    common = ["-o", str(out), "--steps", "1", "--crop", "8", "--frames", "2", "--batch", "1"]
    common += ["--threads", "1", "--no-progress"]
    tiny = ["--config", '{"widths": [8, 8], "kernel_size": 3, "refine_width": 8}']
    res = runner.invoke(app, [str(render_set), *common, *tiny, "--oversample", "lights=3"])
    assert res.exit_code == 0, res.output
    assert "left out 1 incomplete" in res.output and "3 sequence(s) (+2 repeats" in res.output
    meta = read_checkpoint(out)["meta"]
    assert meta["settings"]["oversample"] == {"lights": 3}
    assert [Path(p).name for p in meta["sequences"]] == ["seq_000", "seq_001", "seq_003"]
    for bad in ("lights", "lights=0", "=2", "lights=x"):
        res = runner.invoke(app, [str(render_set), *common, "--oversample", bad])
        assert res.exit_code == 2 and "KIND=N" in res.output, (bad, res.output)
    res = runner.invoke(app, [str(render_set), *common, "--oversample", "water=2"])
    assert res.exit_code == 2 and "'water'" in res.output
