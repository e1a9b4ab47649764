"""`--cluster` (docs/cluster.md): one Ray task per sequence gives exactly what the local run
gives; a failing shot fails alone, by name; a lost worker is retried without rewriting
anything from before the run. One local Ray (2 CPUs) for the whole module."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from rtdenoise.cli.cluster import report_failures
from rtdenoise.cli.common import EXIT_BAD_INPUT, EXIT_FAILURE
from rtdenoise.runtime.sequences.cluster import TaskOutcome
from rtdenoise.shipped import sample_sequences

HAS_RAY = importlib.util.find_spec("ray") is not None
needs_ray = pytest.mark.skipif(
    not HAS_RAY, reason="ray not installed (the cluster extra: pip install 'rtdenoise[cluster]')"
)
runner = CliRunner()


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance with 2 CPUs (about 10 s to start) shared by this module."""
    import ray

    from rtdenoise.runtime.sequences.cluster import connect

    started = connect(num_cpus=2)
    yield
    if started:
        ray.shutdown()


def frames_of(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*.*"))}


def comparable(report: dict, out_dir: Path) -> dict:
    """A sequence's report without what differs between runs: timings, the output folder and
    why a history started (a fresh worker's "first frame", the local loop's "reset()")."""
    report = {k: v for k, v in report.items() if k != "timing_ms"}
    report["frames"] = [
        {
            **row,
            "output": Path(row["output"]).relative_to(out_dir).as_posix(),
            "reset": row["reset"] is not None,
        }
        for row in report["frames"]
    ]
    return report


def test_exit_code_says_whether_all_succeeded(capsys):
    ok = TaskOutcome("a", result={})
    bad_file = TaskOutcome("b", error="InputError: b/f.exr: truncated", input_error=True)
    lost = TaskOutcome("c", error="WorkerCrashedError: lost", attempts=4)
    assert report_failures([ok], "shot") == 0
    assert report_failures([ok, bad_file], "shot") == EXIT_BAD_INPUT
    assert report_failures([ok, bad_file, lost], "shot") == EXIT_FAILURE
    err = capsys.readouterr().err.splitlines()
    assert "error: shot b: InputError: b/f.exr: truncated" in err
    assert "error: shot c (after 4 attempts): WorkerCrashedError: lost" in err


@needs_ray
def test_shots_as_ray_tasks_equal_one_after_another_and_a_broken_shot_fails_alone(
    tmp_path, local_ray
):
    from rtdenoise.cli.run import app

    shots = sample_sequences()
    assert len(shots) == 3
    broken = tmp_path / "broken"
    broken.mkdir()
    for k in range(3):
        shutil.copy(shots[0] / f"frame_{k:04d}.exr", broken)
    data = (broken / "frame_0001.exr").read_bytes()
    (broken / "frame_0001.exr").write_bytes(data[: len(data) // 3])  # truncated
    local, cluster = tmp_path / "local", tmp_path / "cluster"
    common = ["--model", "demo:afn", "--threads", "1"]

    inputs = [str(s) for s in shots]
    res = runner.invoke(
        app, [*inputs, "-o", str(local), *common, "--metrics-json", str(tmp_path / "local.json")]
    )
    assert res.exit_code == 0, res.output
    cluster_json = str(tmp_path / "cluster.json")
    res = runner.invoke(
        app,
        [
            *inputs,
            str(broken),
            "-o",
            str(cluster),
            *common,
            "--cluster",
            "--metrics-json",
            cluster_json,
        ],
    )
    assert res.exit_code == EXIT_BAD_INPUT, res.output
    assert "error: shot broken: InputError: " in res.stderr and "frame_0001.exr" in res.stderr
    assert res.stderr.count("error:") == 1
    assert "seq_002" in res.stdout and "failed" in res.stdout  # the per-shot table

    # Bit-identical outputs and metrics, the broken shot aside.
    expected, got = frames_of(local), frames_of(cluster)
    assert len(expected) == 24
    assert {k: v for k, v in got.items() if not k.startswith("broken/")} == expected
    want = json.loads((tmp_path / "local.json").read_text())
    have = json.loads((tmp_path / "cluster.json").read_text())
    assert [s["name"] for s in have["sequences"]] == ["seq_000", "seq_001", "seq_002"]
    assert [comparable(s, cluster) for s in have["sequences"]] == [
        comparable(s, local) for s in want["sequences"]
    ]
    assert [f["name"] for f in have["failed"]] == ["broken"]
    assert "truncated or corrupt" in have["failed"][0]["error"]

    # A rerun rewrites nothing of a finished shot unless asked: each shot refuses alone.
    stamps = {p: p.stat().st_mtime_ns for p in cluster.rglob("*.exr")}
    res = runner.invoke(app, [*inputs, "-o", str(cluster), *common, "--cluster"])
    assert res.exit_code == EXIT_BAD_INPUT
    assert res.stderr.count("output exists") == 3
    assert {p: p.stat().st_mtime_ns for p in cluster.rglob("*.exr")} == stamps


@needs_ray
def test_a_lost_worker_is_retried_and_the_shot_comes_out_the_same(tmp_path, local_ray):
    from rtdenoise.runtime.sequences.backend import load_backend
    from rtdenoise.runtime.sequences.cluster import run_shots
    from rtdenoise.runtime.sequences.frames import find_frames
    from rtdenoise.runtime.sequences.run import Job, run_sequence

    shot = sample_sequences()[1]
    frames = find_frames(shot)
    reference = run_sequence(
        Job(shot.name, frames, None, tmp_path / "local"),
        load_backend("demo:afn", threads=1),
        "canonical",
        {},
    )
    marker = tmp_path / "first-attempt-died"

    def dying_backend():
        """demo:afn, whose worker process dies at the 4th frame of the first attempt."""
        backend = load_backend("demo:afn", threads=1)
        if marker.exists():
            return backend
        marker.touch()
        process, calls = backend.process, []

        def process_or_die(buffers, **kw):
            calls.append(1)
            if len(calls) == 4:
                os._exit(1)  # the worker is lost: a system failure Ray retries
            return process(buffers, **kw)

        backend.process = process_or_die
        return backend

    done = []
    (outcome,) = run_shots(
        [Job(shot.name, frames, None, tmp_path / "cluster")],
        dying_backend,
        max_retries=1,
        on_done=done.append,
    )
    assert outcome.ok, outcome.error
    assert outcome.attempts == 2 and marker.exists() and done == [outcome]
    assert frames_of(tmp_path / "cluster") == frames_of(tmp_path / "local")
    assert comparable(outcome.result, tmp_path / "cluster") == {
        **comparable(reference, tmp_path / "local"),
        "online": None,
    }


@needs_ray
@pytest.mark.skipif(
    importlib.util.find_spec("mitsuba") is None,
    reason="mitsuba not installed (the data extra; not in the test extra)",
)
def test_render_through_ray_equals_the_local_render(tmp_path, local_ray):
    from rtdenoise.cli.render import app

    args = "-n 2 -f 2 --size 16x12 --spp-ref 4 --seed 7 --start-index 3".split()
    res = runner.invoke(app, [str(tmp_path / "local"), *args])
    assert res.exit_code == 0, res.output
    res = runner.invoke(app, [str(tmp_path / "cluster"), *args, "--cluster"])
    assert res.exit_code == 0, res.output
    local = frames_of(tmp_path / "local")
    assert len(local) == 2 * 5 and "seq_004/meta.json" in local
    assert frames_of(tmp_path / "cluster") == local  # pixels, seeds, cameras, meta: all
