"""The memory-mapped sequence cache (models/cache.py) and the in-memory loader's memory check."""

from __future__ import annotations

import os

import numpy as np
import pytest
from train_data import INPUTS, TINY, write_sequence

import rtdenoise.models.data as data_module
from rtdenoise.models.cache import cache_key, cached_sequence, compact
from rtdenoise.models.data import load_sequence, load_sequences
from rtdenoise.models.train import TrainSettings, train
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr, write_exr


def test_cached_sequence_equals_the_exr_one_and_is_reused(tmp_path, monkeypatch):
    seq_dir = write_sequence(tmp_path / "seq", frames=3, size=16)
    cache = tmp_path / "cache"
    direct = load_sequence(seq_dir, INPUTS)
    mapped = cached_sequence(seq_dir, INPUTS, None, cache)
    assert isinstance(mapped.reference, np.memmap)
    for name in INPUTS:
        np.testing.assert_array_equal(np.asarray(mapped.buffers[name], np.float32),
                                      direct.buffers[name])  # fmt: skip
    np.testing.assert_array_equal(np.asarray(mapped.reference, np.float32), direct.reference)
    (entry,) = [p for p in cache.iterdir() if not p.name.startswith(".")]
    assert entry.name == f"seq-{cache_key(seq_dir, INPUTS, None)}"

    def no_reading(*a, **k):
        raise AssertionError("the cache was converted again")

    monkeypatch.setattr("rtdenoise.models.cache.load_sequence", no_reading)
    again = cached_sequence(seq_dir, INPUTS, None, cache)
    np.testing.assert_array_equal(again.buffers["color"], mapped.buffers["color"])
    monkeypatch.undo()
    # a re-rendered frame gets a new entry
    frame = seq_dir / "frame_0001.exr"
    ch = read_exr(frame)
    ch["R"] = ch["R"] * 2
    write_exr(frame, ch, half=False)
    os.utime(frame, ns=(1, 1))
    fresh = cached_sequence(seq_dir, INPUTS, None, cache)
    np.testing.assert_array_equal(fresh.buffers["color"][1, 0], 2 * direct.buffers["color"][1, 0])
    assert len([p for p in cache.iterdir() if not p.name.startswith(".")]) == 2


def test_compact_keeps_half_only_when_exact():
    half = np.array([0.5, 1.25, 65504.0], np.float32)
    assert compact(half).dtype == np.float16
    assert compact(np.array([0.1, 1e10], np.float32)).dtype == np.float32


def test_training_from_the_cache_equals_training_in_memory(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=3, size=16)
    s = dict(steps=3, crop=16, frames=2, batch=1, seed=1, save_every=0, threads=1)
    quiet = dict(progress=False, log=lambda _: None)
    mem = train(
        [seq_dir], tmp_path / "m.pt", model_config=TINY, settings=TrainSettings(**s), **quiet
    )
    lines = []
    mapped = train([seq_dir], tmp_path / "c.pt", model_config=TINY,
                   settings=TrainSettings(**s, cache=str(tmp_path / "cache")),
                   progress=False, log=lines.append)  # fmt: skip
    assert mapped.losses == mem.losses
    assert any("memory-mapped" in line for line in lines)


def test_in_memory_loading_refuses_what_would_not_fit(tmp_path, monkeypatch):
    seq_dir = write_sequence(tmp_path / "seq", frames=2, size=16)
    one = load_sequence(seq_dir, INPUTS).nbytes
    monkeypatch.setattr(data_module, "available_memory", lambda: 3 * one)
    other = write_sequence(tmp_path / "other", frames=2, size=16, seed=1)
    assert len(load_sequences([seq_dir], INPUTS)) == 1
    assert len(load_sequences([seq_dir] * 2, INPUTS)) == 2  # one folder twice: read once
    with pytest.raises(InputError, match="--cache"):
        load_sequences([seq_dir, other], INPUTS)  # 2 sequences > half of 3
    assert len(load_sequences([seq_dir, other], INPUTS, cache=tmp_path / "c")) == 2


def test_clips_never_cross_a_camera_cut(tmp_path):
    """A rendered sequence's meta.json `cuts` (denoise-render): clips start at or after a cut,
    never across it; a sequence with a cut inside every clip is left out (cache too)."""
    import json

    from rtdenoise.models.data import ClipSampler

    cut = write_sequence(tmp_path / "cut", frames=6, size=16)
    (cut / "meta.json").write_text(json.dumps({"cuts": [3]}))
    plain = write_sequence(tmp_path / "plain", frames=6, size=16, seed=1)
    for loaded in (load_sequences([cut, plain], INPUTS),
                   load_sequences([cut, plain], INPUTS, cache=tmp_path / "c")):  # fmt: skip
        assert loaded[0].cuts == (3,) and loaded[1].cuts == ()
        assert loaded[0].clip_starts(3) == [0, 3] and loaded[1].clip_starts(3) == [0, 1, 2, 3]
        sampler = ClipSampler(loaded, np.random.default_rng(0), frames=3, crop=8, batch=1)
        firsts = set()
        for _ in range(60):
            buffers, reference = sampler.clip()
            firsts.add(float(reference[0, 0, 0, 0]))
        assert len(firsts) > 2
        whole = ClipSampler(loaded, np.random.default_rng(0), frames=6, crop=8, batch=1)
        assert [s.name for s in whole.sequences] == ["plain"]  # the cut one crosses its cut
