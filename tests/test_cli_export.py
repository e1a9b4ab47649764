"""`denoise-export` end to end: writes a validated file, or refuses and writes nothing."""

from __future__ import annotations

import json

import onnx
import pytest
from typer.testing import CliRunner

from rtdenoise.cli.export import app
from rtdenoise.models.checkpoint import save_checkpoint
from rtdenoise.models.registry import build_model

runner = CliRunner()
SMALL_AFN = {"widths": [8, 12], "refine_width": 8, "refine_layers": 2}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    path = tmp_path_factory.mktemp("ckpt") / "afn.pt"
    save_checkpoint(path, build_model("afn", SMALL_AFN), {"note": "untrained"})
    return path


def test_export_writes_validated_model(checkpoint, tmp_path):
    out = tmp_path / "afn.onnx"
    result = runner.invoke(app, [str(checkpoint), "-o", str(out), "--frames", "8", "--size", "32"])
    assert result.exit_code == 0, result.output
    assert "SoftmaxKernelApply x2" in result.output and "AdaptiveFusion x1" in result.output
    model = onnx.load(str(out))
    meta = {p.key: p.value for p in model.metadata_props}
    assert meta["rtdenoise.family"] == "afn"
    assert json.loads(meta["rtdenoise.config"])["widths"] == [8, 12]
    functions = {f.name for f in model.functions}
    assert functions == {"SoftmaxKernelApply", "AdaptiveFusion", "TemporalAccumulation"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afn.onnx"]


def test_export_refuses_when_validation_fails(checkpoint, tmp_path):
    out = tmp_path / "afn.onnx"
    result = runner.invoke(
        app, [str(checkpoint), "-o", str(out), "--size", "32", "--frames", "2", "--tolerance", "-1"]
    )
    assert result.exit_code == 1
    assert "disagrees with PyTorch" in result.output and "not written" in result.output
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content", [None, b"not a checkpoint"])
def test_export_bad_checkpoint_is_one_line_error(tmp_path, content):
    ckpt = tmp_path / "model.pt"
    if content is not None:
        ckpt.write_bytes(content)
    out = tmp_path / "m.onnx"
    result = runner.invoke(app, [str(ckpt), "-o", str(out)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "model.pt" in lines[0]
    assert not out.exists()


def test_export_of_nan_weights_is_one_line_naming_the_weight(tmp_path):
    """A diverged checkpoint (NaN weights) used to fail inside a fast kernel with "SystemError:
    CPUDispatcher ... returned a result with an exception set" (issue 27, item 4)."""
    import torch

    model = build_model("afn", SMALL_AFN)
    name, param = next(iter(model.named_parameters()))
    with torch.no_grad():
        param.view(-1)[:3] = float("nan")
    ckpt = tmp_path / "nan.pt"
    save_checkpoint(ckpt, model, {"note": "diverged"})
    out = tmp_path / "m.onnx"
    result = runner.invoke(app, [str(ckpt), "-o", str(out), "--size", "32", "--frames", "2"])
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    assert f"nan.pt: weight {name!r}" in lines[0] and "has 3 NaN/Inf of" in lines[0]
    assert not out.exists()


def test_export_refuses_to_overwrite_without_the_flag(checkpoint, tmp_path):
    """An existing OUTPUT is kept, named in one line, before any work; --overwrite replaces it."""
    out = tmp_path / "afn.onnx"
    out.write_bytes(b"an earlier export")
    args = [str(checkpoint), "-o", str(out), "--frames", "2", "--size", "32"]
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert lines == [f"error: {out}: exists; --overwrite replaces it"]
    assert out.read_bytes() == b"an earlier export"
    result = runner.invoke(app, [*args, "--overwrite"])
    assert result.exit_code == 0, result.output
    assert onnx.load(str(out)).metadata_props
