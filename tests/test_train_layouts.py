"""`denoise-train --layout`: training reads any layout denoise-run reads (issue 28), converted
at load time the same way, in memory and through the cache; before, the missing-channel error
suggested `--layout blender`, an option denoise-train did not have."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from train_data import INPUTS, write_sequence
from typer.testing import CliRunner

from rtdenoise.cli.train import app
from rtdenoise.models.cache import cache_key, cached_sequence
from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.models.data import load_sequence
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr, write_exr

BLENDER = {  # canonical channel -> the Cycles name the blender preset reads
    **{c: f"ViewLayer.Noisy Image.{c}" for c in "RGB"},
    **{f"albedo.{c}": f"ViewLayer.Denoising Albedo.{c}" for c in "RGB"},
    **{f"normal.{c}": f"ViewLayer.Denoising Normal.{c}" for c in "XYZ"},
    "depth.Z": "ViewLayer.Denoising Depth.Z",
    "motion.X": "ViewLayer.Vector.X",
    "motion.Y": "ViewLayer.Vector.Y",
}


def as_blender(canonical: Path, folder: Path) -> Path:
    """The canonical sequence with a non-zero motion.Y, and the same frames as Cycles writes
    them (Vector.Y points up: minus motion.Y); the references stay R,G,B."""
    folder.mkdir()
    for path in sorted(canonical.glob("*.exr")):
        ch = read_exr(path)
        if path.name.startswith("ref_"):
            write_exr(folder / path.name, ch, half=False)
            continue
        ch["motion.Y"] = np.full_like(ch["motion.Y"], 0.25)
        write_exr(path, ch, half=False)
        cycles = {BLENDER[name]: a for name, a in ch.items()}
        cycles["ViewLayer.Vector.Y"] = -ch["motion.Y"]
        write_exr(folder / path.name, cycles, half=False)
    return folder


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("layouts")
    canonical = write_sequence(root / "canonical", frames=3, size=16)
    return canonical, as_blender(canonical, root / "blender")


def test_a_blender_sequence_loads_as_its_canonical_twin(pair, tmp_path):
    canonical, blender = pair
    want = load_sequence(canonical, INPUTS)
    for got in (
        load_sequence(blender, INPUTS, layout="blender"),
        cached_sequence(blender, INPUTS, None, tmp_path / "cache", "blender"),
    ):
        assert set(got.buffers) == set(INPUTS)
        for name in INPUTS:
            np.testing.assert_array_equal(got.buffers[name], want.buffers[name], err_msg=name)
        np.testing.assert_array_equal(got.reference, want.reference)
    assert np.all(want.buffers["motion"][:, 1] == 0.25)  # the sign conversion was exercised
    # A cache entry of one layout is never read for another.
    assert cache_key(blender, INPUTS, None, "blender") != cache_key(blender, INPUTS, None)
    assert cache_key(canonical, INPUTS, None, "canonical") == cache_key(canonical, INPUTS, None)
    with pytest.raises(InputError, match="try --layout blender"):
        load_sequence(blender, INPUTS)


def test_cli_trains_from_a_blender_sequence(pair, tmp_path):
    _, blender = pair
    out = tmp_path / "b.pt"
    args = [str(blender), "-o", str(out), "--steps", "1", "--crop", "16", "--frames", "2",
            "--batch", "1", "--threads", "1", "--no-progress",
            "--config", '{"widths": [8, 8], "kernel_size": 3, "refine_width": 8}']  # fmt: skip
    res = CliRunner().invoke(app, [*args, "--layout", "blender"])
    assert res.exit_code == 0, res.output
    _, meta = load_checkpoint(out)
    assert meta["settings"]["layout"] == "blender"
    # Without it, the error names the option that exists now.
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2 and "try --layout blender" in res.output
    res = CliRunner().invoke(app, [*args, "--layout", "nosuch"])
    assert res.exit_code == 2 and "nosuch" in res.output
