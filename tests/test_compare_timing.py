"""How `denoise-bench compare` times: every size in every round, a state per size, more frames
for small sizes (runtime/sequences/compare.py). Timing itself is not asserted (benchmarks/
measure it)."""

from __future__ import annotations

import itertools

import numpy as np

from rtdenoise.runtime.sequences import compare

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
    rows, skipped = compare.speed([model, stateless], SIZES, repeats=3)
    assert skipped == []
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


class FakeMemory:
    """Peak and current resident memory that grow with every frame's pixels; fixed free."""

    def __init__(self, bytes_per_pixel: float, available: int) -> None:
        self.used, self.bytes_per_pixel, self.free = 1 << 30, bytes_per_pixel, available

    def frame(self, h: int, w: int) -> None:
        self.used += int(self.bytes_per_pixel * h * w)


def memory_contender(name: str, memory: FakeMemory, log: list) -> compare.Contender:
    def denoise(frame):
        h, w = frame["color"].shape[1:]
        memory.frame(h, w)
        log.append((h, w))

    return compare.Contender(
        name, denoise, lambda: None, ("color",), fresh=lambda: memory_contender(name, memory, log)
    )


def test_a_size_that_would_not_fit_is_left_out_before_its_first_frame(monkeypatch):
    """Three sizes; the third's predicted growth (the second's, scaled by pixels) exceeds the
    memory available: it is never run, and the reason names it and the numbers."""
    monkeypatch.setattr(compare, "SETTLE_S", 0.0)
    monkeypatch.setattr(compare, "synthetic_frames", fake_frames)
    sizes = [(16, 24), (64, 96), (256, 384)]  # the largest: 16x the middle's pixels
    for available, kept in ((10 << 30, 3), (1 << 30, 2)):
        memory = FakeMemory(bytes_per_pixel=1 << 14, available=available)  # 16 KiB per px
        watch = compare.MemoryWatch(lambda m=memory: m.used, lambda m=memory: m.used,
                                    lambda m=memory: m.free)  # fmt: skip
        log: list = []
        rows, skipped = compare.speed(
            [memory_contender("m", memory, log)], sizes, repeats=2, memory=watch
        )
        assert [r["size"] for r in rows] == [list(s) for s in sizes[:kept]]
        assert ((256, 384) in log) == (kept == 3)
        if kept == 2:  # 64x96 warmed up: 16 KiB x 6144 px = 0.09 GiB; x16 x1.5 = 2.25 GiB
            (left_out,) = skipped
            assert left_out["size"] == [256, 384]
            need = compare.MemoryWatch.SAFETY * 16 * (1 << 14) * 64 * 96 / (1 << 30)
            assert left_out["reason"] == (
                "384x256 not timed: warming up 96x64 raised this process's peak memory by "
                f"0.1 GiB, so 384x256 would need about {need:.1f} GiB more, and 1.0 GiB are "
                "available; time fewer models or sizes"
            )
        else:
            assert skipped == []


def test_memory_watch_lets_every_size_through_without_readings():
    watch = compare.MemoryWatch(lambda: None, lambda: None, lambda: None)
    watch.done("24x16", 384)
    watch.done("96x64", 6144)
    assert watch.refuse("3840x2160", 3840 * 2160) is None


def test_quality_runs_a_contenders_cut_before_a_cut_frame():
    """A sequence given with cut indices (a rendered one's meta.json): the contender's `cut`
    runs before those frames, `reset` at the start only."""
    calls = []
    contender = compare.Contender(
        "m", lambda f: f["color"], lambda: calls.append("reset"), ("color",),
        cut=lambda: calls.append("cut"),
    )  # fmt: skip
    frame = {"color": np.ones((3, 4, 4), np.float32)}
    ref = np.ones((3, 4, 4), np.float32)
    compare.quality([contender], [("s", [frame] * 4, [ref] * 4, [2])])
    assert calls == ["reset", "cut"]
