"""denoise-run's progress where stderr is no terminal (issue 28): a plain line per frame and
one line as each fast kernel starts and ends compiling (cli/progress.py); rich's bar on a
terminal."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from progress_lines import is_progress, other_lines
from test_cli_run import invoke, make_sequence

from rtdenoise.cli import run as run_cli
from rtdenoise.cli.progress import kernel_compilation
from rtdenoise.runtime.sequences.backend import PassThrough

numba = pytest.importorskip("numba")


def test_a_pipe_gets_a_plain_line_per_frame(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=3)
    proc = subprocess.run(
        [sys.executable, "-c", "from rtdenoise.cli.run import main; main()", str(seq),
         "-o", str(out), "--model", "none"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == [f"{seq}: frame {k}/3" for k in (1, 2, 3)]
    assert all(is_progress(line) for line in proc.stderr.splitlines())


def test_each_compilation_is_reported_once_with_its_time():
    lines: list[str] = []

    @numba.njit
    def fresh_kernel(x):  # defined here: never in numba's cache
        return x * 2.0 + 1.0

    with kernel_compilation(lines.append):
        assert fresh_kernel(1.0) == 3.0
        assert fresh_kernel(2.0) == 5.0  # compiled already: nothing more to say
    assert fresh_kernel(np.float32(1)) == 3.0  # compiles again, but nobody listens
    assert len(lines) == 2, lines
    assert lines[0] == "compiling fast kernel fresh_kernel (numba; first run only, then cached)"
    assert lines[1].startswith("compiled fast kernel fresh_kernel in ") and lines[1].endswith(" s")
    assert all(is_progress(line) for line in lines)


def test_denoise_run_reports_kernel_compilation_between_its_frames(tmp_path, monkeypatch):
    """The backend's first frame compiles a kernel: the log says so before that frame's line."""

    @numba.njit
    def first_use(x):
        return x + 0.0

    class Compiling(PassThrough):
        def process(self, buffers):
            first_use(1.0)
            return super().process(buffers)

    monkeypatch.setattr(run_cli, "load_backend", lambda *a, **kw: Compiling())
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2)
    res = invoke(seq, "-o", out)
    assert res.exit_code == 0, res.output
    lines = res.stderr.splitlines()
    assert lines[0].startswith("compiling fast kernel first_use ")
    assert lines[1].startswith("compiled fast kernel first_use in ")
    assert lines[2:] == [f"{seq}: frame 1/2", f"{seq}: frame 2/2"]
    assert other_lines(res.stderr) == []


def test_cluster_tasks_report_as_they_end_where_stderr_is_no_terminal(capsys):
    from rich.console import Console

    from rtdenoise.cli.cluster import task_progress
    from rtdenoise.runtime.sequences.cluster import TaskOutcome

    err = Console(stderr=True, force_terminal=False)
    with task_progress(err, {"a": 2, "b": 3}, "denoise") as (on_progress, on_done):
        on_progress({"a": 1})
        on_done(TaskOutcome("b", error="InputError: x"))
        on_done(TaskOutcome("a", result={}))
    assert capsys.readouterr().err.splitlines() == [
        "denoise: b failed (1/2)",
        "denoise: a done (2/2)",
    ]
