"""The committed validation set (validation/, issue 31): what it promises, checked on its files.

Eight 12-frame sequences at 4096 spp from base seed 20000, disjoint from the training set's
scene seeds (base 10000), sequences 0-3 of kinds held out of training (corridor, water), every
frame whole and finite; and the held-out test set (validation/test/): four more of the held-out
kinds from base seed 30000, which nothing was chosen on. Reads headers, meta.json and the
references only (a few seconds).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rtdenoise.datagen.seeds import derive_seed
from rtdenoise.runtime.sequences.exr import read_exr

ROOT = Path(__file__).resolve().parents[1] / "validation"
HELD_OUT = {"corridor", "water"}
TRAIN_SEED, VAL_SEED, TEST_SEED, TRAIN_N = 10000, 20000, 30000, 10000
SEQUENCES = [ROOT / f"seq_{i:03d}" for i in range(8)]
TEST_SEQUENCES = [ROOT / "test" / f"seq_{i:03d}" for i in range(4)]


def _meta(seq: Path) -> dict:
    return json.loads((seq / "meta.json").read_text())


def test_every_sequence_is_complete_and_as_documented():
    assert sorted(p.name for p in ROOT.glob("seq_*")) == [p.name for p in SEQUENCES]
    for i, seq in enumerate(SEQUENCES):
        meta = _meta(seq)
        assert meta["frame_count"] == 12 and meta["resolution"] == [128, 128], seq.name
        assert meta["spp"]["ref"] == 4096 and meta["spp"]["color"] == 1, seq.name
        if not meta["redraws"]:  # a refused draw renders a derived seed instead
            assert meta["scene_seed"] == derive_seed(VAL_SEED, i), seq.name
        assert (meta["kind"] in HELD_OUT) == (i < 4), (seq.name, meta["kind"])
        for t in range(12):
            assert (seq / f"frame_{t:04d}.exr").is_file() and (seq / f"ref_{t:04d}.exr").is_file()
        assert not (seq / "partial.json").exists()


def test_the_test_set_is_complete_held_out_and_from_its_own_seeds():
    assert sorted(p.name for p in (ROOT / "test").glob("seq_*")) == [p.name for p in TEST_SEQUENCES]
    validation = {_meta(seq)["scene_seed"] for seq in SEQUENCES}
    for i, seq in enumerate(TEST_SEQUENCES):
        meta = _meta(seq)
        assert meta["frame_count"] == 12 and meta["resolution"] == [128, 128], seq.name
        assert meta["spp"]["ref"] == 4096 and meta["spp"]["color"] == 1, seq.name
        assert meta["kind"] in HELD_OUT, (seq.name, meta["kind"])
        if not meta["redraws"]:
            assert meta["scene_seed"] == derive_seed(TEST_SEED, i), seq.name
        assert meta["scene_seed"] not in validation, seq.name
        for t in range(12):
            assert (seq / f"frame_{t:04d}.exr").is_file() and (seq / f"ref_{t:04d}.exr").is_file()
        assert not (seq / "partial.json").exists()


def test_no_scene_of_the_training_set():
    train = {derive_seed(TRAIN_SEED, i) for i in range(TRAIN_N)}
    for seq in SEQUENCES + TEST_SEQUENCES:
        meta = _meta(seq)
        seeds = {meta["scene_seed"], *(r["scene_seed"] for r in meta["redraws"])}
        assert not seeds & train, seq.name


@pytest.mark.parametrize(
    "seq", SEQUENCES + TEST_SEQUENCES, ids=lambda p: f"{p.parent.name}/{p.name}"
)
def test_references_are_finite_and_lit(seq):
    for t in range(12):
        ref = read_exr(str(seq / f"ref_{t:04d}.exr"))
        rgb = np.stack([ref["R"], ref["G"], ref["B"]]).astype(np.float32)
        assert np.isfinite(rgb).all() and rgb.min() >= 0.0, (seq.name, t)
        assert rgb.mean() > 1e-3, (seq.name, t)  # not a black frame
