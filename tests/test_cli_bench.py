"""`denoise-bench` runs end to end at a tiny size (timings are for benchmarks, not tests)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from rtdenoise.cli.bench import app

runner = CliRunner()


def test_bench_model_reports_every_path_and_stage(tmp_path):
    out = tmp_path / "bench.json"
    res = runner.invoke(
        app, ["model", "demo:afn", "--size", "40x24", "--repeats", "1", "--json", str(out)]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert set(data["model_ms"]) == {"torch", "torch_deployed", "ort_fast", "ort_portable"}
    ops = sorted((s["op"], tuple(s["shape"][2:])) for s in data["stages"])
    assert ops == [
        ("AdaptiveFusion", (24, 40)),
        ("KernelApply", (12, 20)),
        ("KernelApply", (24, 40)),
    ]
    assert all(s["calls_per_frame"] == 1 for s in data["stages"])


def test_bench_op_and_its_errors():
    res = runner.invoke(
        app,
        [
            "op",
            "WeightSharingFilter",
            "--size",
            "24x16",
            "--repeats",
            "1",
            "--attr",
            "size_min=13",
            "--attr",
            "count=1",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "ORT portable" in res.output and "largest difference" in res.output
    res = runner.invoke(app, ["op", "Nope"])
    assert res.exit_code == 2 and "unknown op 'Nope'" in res.output
    res = runner.invoke(app, ["op", "KernelApply", "--attr", "sizes=3"])
    assert res.exit_code == 2 and "--attr 'sizes=3'" in res.output
