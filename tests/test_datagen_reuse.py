"""References reused from a set rendered before (`denoise-render --references-from`): the
copied references are the ones a full render would make, the inputs are rendered anew, and a
source of other shots is refused with the field that differs (skips without mitsuba)."""

from __future__ import annotations

import dataclasses
import importlib.util
import json

import numpy as np
import pytest

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("mitsuba") is None, reason="mitsuba not installed ([data] extra)"
)

SEED = 7


def _render(folder, cfg, **kwargs):
    from rtdenoise.datagen.render import render_sequence
    from rtdenoise.datagen.variant import select_variant

    select_variant("scalar_rgb")
    return render_sequence(folder, SEED, cfg, variant="scalar_rgb", **kwargs)


@pytest.fixture(scope="module")
def cfg():
    from rtdenoise.datagen.render import RenderConfig

    return RenderConfig(20, 16, 3, spp_ref=16, half=True, kinds=("room",))


@pytest.fixture(scope="module")
def source(tmp_path_factory, cfg):
    folder = tmp_path_factory.mktemp("source")
    _render(folder, cfg)
    return folder


@pytest.fixture(scope="module")
def per_sample(tmp_path_factory, cfg):
    """The source's shots rendered again with 2 samples per pixel, without reuse."""
    folder = tmp_path_factory.mktemp("full")
    _render(folder, dataclasses.replace(cfg, samples=2))
    return folder


def test_reused_references_are_the_ones_a_full_render_makes(tmp_path, cfg, source, per_sample):
    meta = _render(tmp_path, dataclasses.replace(cfg, samples=2), references_from=source)
    assert meta["references_from"] == str(source) and meta["samples"] == 2
    full = json.loads((per_sample / "meta.json").read_text())
    assert meta["spp"] == full["spp"] and meta["exposure"] == full["exposure"]
    for t in range(cfg.frames):
        ref = (tmp_path / f"ref_{t:04d}.exr").read_bytes()
        assert ref == (source / f"ref_{t:04d}.exr").read_bytes()
        assert ref == (per_sample / f"ref_{t:04d}.exr").read_bytes()  # samples never touch it
        ours, theirs = (
            read_exr(tmp_path / f"frame_{t:04d}.exr"),
            read_exr(per_sample / f"frame_{t:04d}.exr"),
        )
        assert "sample1.R" in ours and sorted(ours) == sorted(theirs)
        for name in ours:
            np.testing.assert_array_equal(ours[name], theirs[name], err_msg=name)
        one_spp = read_exr(source / f"frame_{t:04d}.exr")["R"]
        assert not np.array_equal(ours["R"], one_spp)  # the input is rendered anew: 2 spp
    assert not list(tmp_path.glob(".*tmp*"))


def test_the_source_lends_its_exposure(tmp_path, cfg, source, per_sample):
    """The references were scaled by the source's exposure (its pilot render can differ in the
    last digits between runs), so the inputs are scaled by it too."""
    import shutil

    lender = tmp_path / "lender"
    shutil.copytree(source, lender)
    meta = json.loads((lender / "meta.json").read_text())
    meta["exposure"] *= 2.0
    (lender / "meta.json").write_text(json.dumps(meta))
    out = _render(tmp_path / "out", dataclasses.replace(cfg, samples=2), references_from=lender)
    assert out["exposure"] == meta["exposure"]
    ours, theirs = (
        read_exr(tmp_path / "out" / "frame_0001.exr"),
        read_exr(per_sample / "frame_0001.exr"),
    )
    np.testing.assert_allclose(ours["sample1.R"], 2.0 * theirs["sample1.R"], rtol=2e-3, atol=1e-6)
    np.testing.assert_array_equal(ours["depth.Z"], theirs["depth.Z"])


def test_a_source_of_other_shots_is_refused_naming_what_differs(tmp_path, cfg, source):
    other = dataclasses.replace(cfg, spp_ref=32)
    with pytest.raises(InputError, match="reference spp"):
        _render(tmp_path / "a", other, references_from=source)
    with pytest.raises(InputError, match="no meta.json"):
        _render(tmp_path / "b", cfg, references_from=tmp_path / "nowhere")
    from rtdenoise.datagen.render import render_sequence

    with pytest.raises(InputError, match="scene"):
        render_sequence(tmp_path / "c", SEED + 1, cfg, variant="scalar_rgb", references_from=source)
    for name in ("a", "b", "c"):  # refused before anything was written
        assert not list((tmp_path / name).iterdir())


def test_the_cli_reuses_a_set_and_refuses_a_missing_one(tmp_path, cfg):
    from typer.testing import CliRunner

    from rtdenoise.cli.render import app

    args = ["--seed", "3", "--frames", "2", "--size", "16x16", "--spp-ref", "8", "--kinds", "room"]
    runner = CliRunner()
    first = runner.invoke(app, [str(tmp_path / "one"), *args])
    assert first.exit_code == 0, first.output
    again = runner.invoke(
        app,
        [
            str(tmp_path / "two"),
            *args,
            "--samples",
            "2",
            "--references-from",
            str(tmp_path / "one"),
        ],
    )
    assert again.exit_code == 0, again.output
    meta = json.loads((tmp_path / "two" / "seq_000" / "meta.json").read_text())
    assert meta["references_from"] == str(tmp_path / "one" / "seq_000")
    more = runner.invoke(
        app, [str(tmp_path / "two"), *args, "-n", "2", "--samples", "2", "--references-from",
              str(tmp_path / "one")],
    )  # fmt: skip
    assert more.exit_code == 0 and "leaving out 1 sequence(s) not complete" in more.output
    assert not (tmp_path / "two" / "seq_001").exists()
    missing = runner.invoke(app, [str(tmp_path / "three"), *args, "--references-from", "nowhere"])
    assert missing.exit_code == 2 and "nowhere" in missing.output
    mismatched = runner.invoke(
        app,
        [str(tmp_path / "four"), *args[:-2], "--kinds", "glass", "--references-from",
         str(tmp_path / "one")],
    )  # fmt: skip
    assert mismatched.exit_code == 2 and "its scene differs" in mismatched.output
