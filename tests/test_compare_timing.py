"""How `denoise-bench compare` times: every size in every round, a state per size, more frames
for small sizes (runtime/compare.py). Timing itself is not asserted (benchmarks/ measure it)."""

from __future__ import annotations

import itertools

import numpy as np

from rtdenoise.runtime import compare

SIZES = [(16, 24), (720, 1280)]


def recording_contender(name: str, log: list, ids: itertools.count) -> compare.Contender:
    """A stateful fake: each instance has an id and logs (name, id, frame size) per frame."""
    me = next(ids)

    def denoise(frame):
        log.append((name, me, frame["color"].shape[1:]))

    def fresh():
        return recording_contender(name, log, ids)

    return compare.Contender(name, denoise, lambda: None, ("color",), fresh=fresh)


def fake_frames(buffers, n, h, w, **kwargs):
    return [{"color": np.zeros((3, h, w), np.float32)} for _ in range(n)]


def test_sizes_interleave_each_with_its_own_state(monkeypatch):
    monkeypatch.setattr(compare, "SETTLE_S", 0.0)
    monkeypatch.setattr(compare, "synthetic_frames", fake_frames)
    log: list = []
    ids = itertools.count()
    model = recording_contender("model", log, ids)
    stateless = compare.Contender("oidn", lambda f: log.append(("oidn", -1, f["color"].shape[1:])),
                                  lambda: None, ("color",))  # fmt: skip
    rows = compare.speed([model, stateless], SIZES, repeats=3)
    small, large = rows
    assert small["repeats"] == 3 * compare.MORE_FRAMES_UP_TO and large["repeats"] == 3
    assert len(small["times_ms"]["model"]) == 12 and len(large["times_ms"]["oidn"]) == 3
    # one model instance per size, each seeing only its size; the stateless one serves both
    per_instance = {(n, i): {s for n2, i2, s in log if (n2, i2) == (n, i)} for n, i, _ in log}
    models = {k: v for k, v in per_instance.items() if k[0] == "model"}
    assert len(models) == 2 and all(len(v) == 1 for v in models.values())
    # every round visits both sizes: the timed part alternates 4 small frames and 1 large
    sizes = [s for n, _, s in log if n == "model"]
    timed = sizes[2:]  # after the warm-up round (one frame per size)
    assert timed == ([(16, 24)] * 4 + [(720, 1280)]) * 3


def test_frames_per_round_by_size():
    assert compare.frames_per_round(720, 1280) == 1
    assert compare.frames_per_round(1080, 1920) == 1
    assert compare.frames_per_round(480, 640) == 3  # 921600 / 307200
    assert compare.frames_per_round(240, 320) == compare.MORE_FRAMES_UP_TO
