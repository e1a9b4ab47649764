"""rtdenoise.runtime.sequences.run: the per-sequence job without the CLI (callbacks, backend
contract)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.exr import read_exr, write_exr
from rtdenoise.runtime.sequences.frames import frame_number
from rtdenoise.runtime.sequences.layouts import get_layout
from rtdenoise.runtime.sequences.run import Job, run_sequence

H, W = 8, 10


def make_frames(folder: Path, n: int = 3, refs: bool = True) -> list[Path]:
    """Canonical frames with color, albedo, depth and an unused layer; refs ref_000k.exr."""
    rng = np.random.default_rng(0)
    for k in range(1, n + 1):
        ch = {c: rng.random((H, W), dtype=np.float32) for c in "RGB"}
        ch |= {f"albedo.{c}": np.full((H, W), 0.5, np.float32) for c in "RGB"}
        ch |= {"depth.Z": np.ones((H, W), np.float32), "junk.Q": np.zeros((H, W), np.float32)}
        write_exr(folder / f"frame_{k:04d}.exr", ch, half=False)
        if refs:
            write_exr(folder / f"ref_{k:04d}.exr", {c: ch[c] for c in "RGB"}, half=False)
    return sorted(folder.glob("frame_*.exr"))


class Recorder:
    """A backend that records what it is given and returns color (or a NaN frame)."""

    def __init__(self, required: tuple[str, ...] | None = ("color", "albedo"), nan_at=()):
        if required is not None:
            self.required_buffers = required
        self.calls: list[dict[str, np.ndarray]] = []
        self.nan_at = set(nan_at)
        self.resets = 0
        self.last: np.ndarray | None = None

    def process(self, buffers):
        self.calls.append({k: v.copy() for k, v in buffers.items()})
        self.last = np.array(buffers["color"])
        if len(self.calls) - 1 in self.nan_at:
            self.last[:, 0, 0] = np.nan
        return self.last  # its own array: run_sequence must not modify it

    def reset(self):
        self.resets += 1


def test_backend_gets_only_its_buffers_sanitised(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    frames = make_frames(seq)
    ch = read_exr(frames[1])
    ch["albedo.G"][2, 3] = np.inf
    write_exr(frames[1], ch, half=False)
    backend, advanced, warnings = Recorder(nan_at={2}), [], []
    report = run_sequence(
        Job("s", frames, None, tmp_path / "out"),
        backend,
        get_layout("canonical"),
        {},
        on_frame=lambda: advanced.append(1),
        on_warning=warnings.append,
    )
    assert backend.resets == 1 and len(advanced) == 3
    assert [set(b) for b in backend.calls] == [{"color", "albedo"}] * 3
    assert all(np.isfinite(b).all() for buffers in backend.calls for b in buffers.values())
    assert backend.calls[1]["albedo"][1, 2, 3] == 0
    assert [r["nonfinite"] for r in report["frames"]] == [0, 1, 0]
    assert warnings == [
        f"{frames[1]}: 1 pixels with NaN/Inf in albedo replaced",
        f"{frames[2]}: 1 non-finite output pixels replaced by 0",
    ]
    assert np.isnan(backend.last[0, 0, 0])  # the backend's array was copied, not modified
    out = read_exr(tmp_path / "out" / "frame_0003.exr")
    assert out["R"][0, 0] == 0 and np.isfinite(out["R"]).all()
    assert report["mean"] is not None and set(report["timing_ms"]) == {"read", "denoise", "write"}


def test_backend_without_required_buffers_gets_every_buffer(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    frames = make_frames(seq, n=2, refs=False)
    backend = Recorder(required=None)
    report = run_sequence(
        Job("s", frames, None, tmp_path / "out"), backend, get_layout("canonical"), {}
    )
    assert set(backend.calls[0]) == {"color", "albedo", "depth"}
    assert report["mean"] is None and [r["psnr"] for r in report["frames"]] == [None, None]


def test_nothing_written_when_a_later_frame_is_bad(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    frames = make_frames(seq)
    ch = read_exr(frames[2])
    del ch["albedo.B"]
    write_exr(frames[2], ch, half=False)
    with pytest.raises(InputError, match=r"frame_0003\.exr: missing channel albedo\.B"):
        run_sequence(Job("s", frames, None, tmp_path / "out"), Recorder(), "canonical", {})
    assert not (tmp_path / "out").exists()
    run_sequence(Job("s", frames, None, tmp_path / "o2"), Recorder(("color",)), "canonical", {})
    assert len(list((tmp_path / "o2").glob("*.exr"))) == 3  # albedo unused: fine


SCRIPT = textwrap.dedent(
    """
    import json, sys
    sys.modules["torch"] = None  # any `import torch` now raises ImportError
    from pathlib import Path
    import rtdenoise.runtime.sequences.run as run
    from rtdenoise.runtime.sequences.backend import PassThrough
    from rtdenoise.runtime.sequences.frames import find_frames

    seq, out = Path(sys.argv[1]), Path(sys.argv[2])
    report = run.run_sequence(run.Job("s", find_frames(seq), None, out), PassThrough(),
                              "canonical", {})
    print(json.dumps({
        "torch": repr(sys.modules.get("torch", "absent")),
        "loaded": sorted(m for m, mod in sys.modules.items()
                         if mod is not None and m.split(".")[0] in ("torch", "onnxruntime")),
        "frames": len(report["frames"]),
    }))
    """
)


def test_runtime_run_imports_and_runs_without_torch(tmp_path):
    seq = tmp_path / "seq"
    seq.mkdir()
    make_frames(seq, n=2)
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(seq), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    # torch still blocked, and pass-through did not even load ONNX Runtime
    assert result == {"torch": "None", "loaded": [], "frames": 2}


def test_a_camera_cut_in_meta_json_resets_the_history(tmp_path):
    """A rendered sequence's meta.json `cuts` (denoise-render): the backend is reset before
    that frame, with no warning (a cut is no gap)."""
    seq = tmp_path / "seq"
    seq.mkdir()
    frames = make_frames(seq)
    (seq / "meta.json").write_text(json.dumps({"cuts": [frame_number(frames[1])]}))
    backend, warnings = Recorder(), []
    run_sequence(
        Job("s", frames, None, tmp_path / "out"),
        backend,
        get_layout("canonical"),
        {},
        on_frame=lambda: None,
        on_warning=warnings.append,
    )
    assert backend.resets == 2 and warnings == []  # the start, then the cut
