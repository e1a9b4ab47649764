"""The PyTorch side on a GPU: every shipped model on CUDA gives the CPU's numbers frame after
frame, `denoise-train --device cuda` trains a checkpoint that exports and validates, and
`denoise-bench compare --device cuda` times eager and OIDN there with the CPU's quality.

They run where torch sees a CUDA device (scripts/device_check.sh runs them on a lent GPU
machine) and skip elsewhere. RTDENOISE_TEST_DEVICE=cpu runs them against the CPU itself, which
checks the tests, not a GPU.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
from test_train import write_sequence
from typer.testing import CliRunner

from rtdenoise.cli.bench import app as bench_app
from rtdenoise.cli.train import app as train_app
from rtdenoise.export.deploy import to_deploy
from rtdenoise.export.pipeline import export_checkpoint
from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
from rtdenoise.shipped import demo_model, sample_sequences

DEVICE = os.environ.get("RTDENOISE_TEST_DEVICE", "cuda")
pytestmark = pytest.mark.skipif(
    DEVICE.startswith("cuda") and not torch.cuda.is_available(),
    reason="no CUDA device (RTDENOISE_TEST_DEVICE=cpu runs these tests against the CPU)",
)
FAMILIES = ("afn", "wskp", "nbg", "affinity", "crossreg")
runner = CliRunner()


@pytest.fixture(autouse=True)
def full_float32():
    """TF32 convolutions and matmuls (on by default for cuDNN) would round to 10-bit mantissas:
    compare float32 with float32."""
    if not torch.cuda.is_available():
        yield
        return
    conv, matmul = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    yield
    torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = conv, matmul


def _frames_out(model: torch.nn.Module, frames: list, device: str) -> list[np.ndarray]:
    loop = FrameLoop(model.to(device))
    with torch.no_grad():  # crossreg takes its online gradient inside (enable_grad)
        return [loop(f).cpu().numpy() for f in frames]


@pytest.mark.parametrize("family", FAMILIES)
def test_shipped_model_on_the_device_gives_the_cpu_numbers(family):
    """Deployed form, 6 frames of 64x64 with the state carried (crossreg: learning while it
    runs): the device's output within 1e-3 of the CPU's, relative to the output's range."""
    net, _ = load_checkpoint(demo_model(family, ".pt"))
    net = to_deploy(net.eval(), inplace=True).requires_grad_(False)
    frames = synthetic_frames(net.inputs, 6, 64, 64, seed=1)
    cpu = _frames_out(net, frames, "cpu")
    dev = _frames_out(net, frames, DEVICE)
    for t, (a, b) in enumerate(zip(cpu, dev, strict=True)):
        assert np.isfinite(b).all(), f"frame {t}"
        err = float(np.abs(a - b).max()) / max(float(np.abs(a).max()), 1e-6)
        assert err <= 1e-3, f"frame {t}: relative error {err:.2e}"


def test_train_on_the_device_exports_a_validated_model(tmp_path):
    data = write_sequence(tmp_path / "seq_a")
    ckpt = tmp_path / "gpu.pt"
    args = [str(data), "-o", str(ckpt), "--family", "wskp", "--device", DEVICE]
    args += ["--steps", "4", "--crop", "24", "--frames", "3", "--batch", "2"]
    res = runner.invoke(train_app, args)
    assert res.exit_code == 0, res.output
    model, meta = load_checkpoint(ckpt)  # onto the CPU
    assert next(model.parameters()).device.type == "cpu"
    report = export_checkpoint(ckpt, tmp_path / "gpu.onnx", frames=4)
    assert report.validation.passed and (tmp_path / "gpu.onnx").is_file()


def test_compare_on_the_device_times_eager_and_oidn_with_the_cpu_quality(tmp_path):
    pytest.importorskip("pyoidn")
    seq = str(sample_sequences()[0])
    runs = {}
    for device in ("cpu", DEVICE):
        out = tmp_path / f"{device}.json"
        args = ["compare", "demo:wskp", "--eager", "--device", device, "--oidn", "fast"]
        args += ["--size", "48x32", "--repeats", "1", "--sequence", seq, "--json", str(out)]
        res = runner.invoke(bench_app, args)
        assert res.exit_code == 0, res.output
        runs[device] = json.loads(out.read_text())
    data = runs[DEVICE]
    assert data["device"] == DEVICE
    kind = torch.device(DEVICE).type
    eager = f"demo:wskp (PyTorch {kind})"
    oidn = "OIDN fast" if kind == "cpu" else f"OIDN fast ({kind})"
    assert {eager, oidn} <= set(data["speed"][0]["times_ms"])
    q, q_cpu = data["quality"], runs["cpu"]["quality"]
    assert q[eager]["mean"]["psnr"] == pytest.approx(q["demo:wskp"]["mean"]["psnr"], abs=1e-2)
    assert q[oidn]["mean"]["psnr"] == pytest.approx(q_cpu["OIDN fast"]["mean"]["psnr"], abs=0.1)
    assert q[oidn]["mean"]["psnr"] > data["noisy"]["mean"]["psnr"] + 6.0
