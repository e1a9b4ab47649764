"""EXR data and display windows: outputs keep the input's; a data window that moves
mid-sequence resets the history with a warning (issue 27, item 8)."""

from __future__ import annotations

import json

import numpy as np
from test_bad_input import H, W, make_files
from test_cli_run import invoke

from rtdenoise.runtime.sequences.exr import read_exr, read_exr_windows, write_exr

DISPLAY = ((0, 0), (W + 40, H + 30))


def at(x: int, y: int):
    return ((x, y), (x + W - 1, y + H - 1))


def place(path, window):
    """Rewrite a frame with its pixels at `window` on the DISPLAY canvas."""
    write_exr(path, read_exr(path), half=False, windows=(window, DISPLAY))


def test_write_and_read_windows(tmp_path):
    path = tmp_path / "f.exr"
    write_exr(path, {"R": np.ones((H, W), np.float32)}, windows=(at(7, 5), DISPLAY))
    assert read_exr_windows(path) == (at(7, 5), DISPLAY)
    assert read_exr(path)["R"].shape == (H, W)


def test_outputs_keep_the_windows_and_a_moved_window_resets(tmp_path):
    seq, out, js = tmp_path / "seq", tmp_path / "out", tmp_path / "m.json"
    make_files(seq, range(1, 4))
    windows = [at(10, 20), at(10, 20), at(12, 20)]
    for k, window in enumerate(windows, 1):
        place(seq / f"frame_{k:04d}.exr", window)
    res = invoke(seq, "-o", out, "--model", "demo:wskp", "--threads", "1", "--metrics-json", js)
    assert res.exit_code == 0, res.output
    for k, window in enumerate(windows, 1):
        assert read_exr_windows(out / f"frame_{k:04d}.exr") == (window, DISPLAY)
    lines = [line for line in res.stderr.splitlines() if "data window" in line]
    assert len(lines) == 1 and "frame_0003.exr: data window (12,20)-" in lines[0]
    assert "differs from the previous frame's (10,20)-" in lines[0] and "history reset" in lines[0]
    rows = json.loads(js.read_text())["frames"]
    assert rows[1]["reset"] is None and rows[2]["reset"]
