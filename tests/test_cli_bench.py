"""`denoise-bench` runs end to end at a tiny size (timings are for benchmarks, not tests)."""

from __future__ import annotations

import json
import sys

import pytest
from typer.testing import CliRunner

from rtdenoise.cli.bench import app
from rtdenoise.shipped import sample_sequences

runner = CliRunner()


def test_bench_model_reports_every_path_and_stage(tmp_path, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # one table row per line
    out = tmp_path / "bench.json"
    # 48x32: a multiple of demo:afn's pad multiple (16), so the stages see the given size
    res = runner.invoke(
        app, ["model", "demo:afn", "--size", "48x32", "--repeats", "1", "--json", str(out)]
    )
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert set(data["model_ms"]) == {"torch", "torch_deployed", "ort_fast", "ort_portable"}
    ops = sorted((s["op"], tuple(s["shape"][2:])) for s in data["stages"])
    assert ops == [
        ("AdaptiveFusion", (32, 48)),
        ("SoftmaxKernelApply", (16, 24)),
        ("SoftmaxKernelApply", (32, 48)),
        ("TemporalAccumulation", (32, 48)),
    ]
    assert all(s["calls_per_frame"] == 1 for s in data["stages"])
    # stages are labelled WIDTHxHEIGHT, as --size is given (the tensors are N, C, H, W)
    assert "SoftmaxKernelApply 48x32 x1" in res.output
    assert "SoftmaxKernelApply 24x16 x1" in res.output
    assert "afn at 48x32" in res.output


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


def test_compare_models_and_oidn_at_a_tiny_size(tmp_path, monkeypatch):
    """Two sizes, a shipped model on both ORT paths and OIDN fast, quality on one sequence;
    every session on the process's shared CPU arena."""
    pytest.importorskip("pyoidn")
    import rtdenoise.runtime.denoiser as denoiser_module

    made = []

    class Recorded(denoiser_module.Denoiser):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            made.append(self)

    monkeypatch.setattr(denoiser_module, "Denoiser", Recorded)
    out, plot = tmp_path / "c.json", tmp_path / "c.png"
    seq = str(sample_sequences()[0])
    args = ["compare", "demo:wskp", "--portable", "--oidn", "fast", "--size", "24x16"]
    args += ["--size", "48x32", "--repeats", "2", "--sequence", seq, "--json", str(out)]
    res = runner.invoke(app, [*args, "--plot", str(plot)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["nchwc_block"] in (8, 16)  # which conv forms the models ran in
    names = {"demo:wskp", "demo:wskp (portable)", "OIDN fast"}
    assert [r["size"] for r in data["speed"]] == [[16, 24], [32, 48]]
    for row in data["speed"]:
        n = row["repeats"]
        assert n == 8  # --repeats 2 at 720p; tiny frames get the most, 4x
        assert set(row["times_ms"]) == names and all(len(t) == n for t in row["times_ms"].values())
        s = row["summary"]["OIDN fast"]
        assert s["min_ms"] <= s["median_ms"] <= s["max_ms"]
        assert s["ns_per_pixel"] == pytest.approx(
            s["median_ms"] * 1e6 / (row["size"][0] * row["size"][1])
        )
    q = data["quality"]
    # the same shipped model scores the same on both paths, and every denoiser beats the input
    assert q["demo:wskp"]["mean"]["psnr"] == pytest.approx(
        q["demo:wskp (portable)"]["mean"]["psnr"], abs=1e-3
    )
    for name in names:
        assert q[name]["mean"]["psnr"] > data["noisy"]["mean"]["psnr"] + 6.0
        # every score per sequence and as the mean; SMAPE and relMSE below the input's
        (per_seq,) = q[name]["sequences"].values()
        assert set(per_seq) == set(q[name]["mean"]) == {"psnr", "ssim", "smape", "relmse", "trmae"}
        assert q[name]["mean"]["smape"] < data["noisy"]["mean"]["smape"]
        assert q[name]["mean"]["relmse"] < data["noisy"]["mean"]["relmse"]
    for column in ("SMAPE", "relMSE", "TRMAE"):
        assert column in res.stdout
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(made) == 4 and all(d.shared_arena for d in made)  # 2 paths x 2 sizes
    # not a terminal: the progress as plain lines on stderr, not lost with rich's status line
    for line in ("comparing: warming up 24x16", "comparing: round 2 of 2", "comparing: quality"):
        assert line in res.stderr


def test_compare_without_pyoidn_says_what_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    res = runner.invoke(app, ["compare", "demo:wskp", "--size", "8x8", "--repeats", "1"])
    assert res.exit_code == 2
    assert "pip install 'rtdenoise[bench]'" in res.output


def test_compare_eager_is_the_deployed_model_of_the_same_checkpoint(tmp_path):
    """--eager adds PyTorch eager of each model (a per-sample one and one that learns while it
    runs included): same quality as ORT, timed beside it."""
    out = tmp_path / "c.json"
    seq = str(sample_sequences()[1])
    args = ["compare", "demo:wskp", "demo:affinity", "demo:crossreg", "--eager", "--oidn", "none"]
    args += ["--size", "24x16", "--repeats", "1", "--sequence", seq, "--json", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["device"] == "cpu"
    for spec in ("demo:wskp", "demo:affinity", "demo:crossreg"):
        eager = f"{spec} (PyTorch cpu)"
        assert set(data["speed"][0]["times_ms"]) >= {spec, eager}
        q = data["quality"]
        assert q[eager]["mean"]["psnr"] == pytest.approx(q[spec]["mean"]["psnr"], abs=1e-3)
        assert q[spec]["mean"]["psnr"] > data["noisy"]["mean"]["psnr"] + 6.0


def test_compare_eager_needs_a_checkpoint_and_a_usable_device(tmp_path):
    from rtdenoise.shipped import MODELS_DIR

    onnx_only = str(MODELS_DIR / "wskp.onnx")
    res = runner.invoke(app, ["compare", onnx_only, "--eager", "--size", "8x8", "--oidn", "none"])
    assert res.exit_code == 2 and "has no PyTorch checkpoint" in res.output
    res = runner.invoke(app, ["compare", "demo:wskp", "--device", "tpu:0", "--size", "8x8"])
    assert res.exit_code == 2 and "device 'tpu:0'" in res.output


def test_compare_keeps_sequences_of_the_same_folder_name_apart(tmp_path):
    """validation/seq_000 and sequences/seq_000 are two sequences, scored and reported apart
    (named as denoise-run names shots), not one overwriting the other."""
    import shutil

    src = sample_sequences()[0]
    for parent, keep in (("a", 2), ("b", 3)):
        dst = tmp_path / parent / src.name
        dst.mkdir(parents=True)
        for i in range(keep):
            for kind in ("frame", "ref"):
                shutil.copy(src / f"{kind}_{i:04d}.exr", dst)
    out = tmp_path / "c.json"
    args = ["compare", "demo:wskp", "--oidn", "none", "--size", "8x8", "--repeats", "1"]
    for parent in ("a", "b"):
        args += ["--sequence", str(tmp_path / parent / src.name)]
    res = runner.invoke(app, args + ["--json", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert set(data["noisy"]["sequences"]) == {f"a/{src.name}", f"b/{src.name}"}
    per_seq = data["quality"]["demo:wskp"]["sequences"]
    assert per_seq[f"a/{src.name}"]["psnr"] != per_seq[f"b/{src.name}"]["psnr"]  # 2 vs 3 frames
