"""`--device`: checked before any work, with an error that says what is possible."""

from __future__ import annotations

import pytest
import torch
from typer.testing import CliRunner

from rtdenoise.cli.train import app as train_app
from rtdenoise.models.device import DeviceError, model_device, torch_device
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.sequences.synthetic import synthetic_frames

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")


def test_cpu_and_unknown_devices():
    assert torch_device("cpu") == torch.device("cpu")
    with pytest.raises(DeviceError, match="unknown device 'gpu7'"):
        torch_device("gpu7")


@no_cuda
def test_cuda_without_cuda_says_so():
    with pytest.raises(DeviceError, match="no usable CUDA device"):
        torch_device("cuda")


@no_cuda
def test_train_refuses_an_unusable_device_before_reading_data(tmp_path):
    res = CliRunner().invoke(
        train_app,
        [str(tmp_path / "missing"), "-o", str(tmp_path / "c.pt"), "--device", "cuda"],
    )
    assert res.exit_code == 2 and "no usable CUDA device" in res.output
    assert not (tmp_path / "c.pt").exists()


def test_frame_loop_moves_numpy_frames_to_the_model_device():
    """Frames given as numpy arrays run on the model's device (CPU here; CUDA on a GPU)."""
    torch.manual_seed(0)
    model = build_model("wskp", {"layers": 2, "width": 8}).eval()
    assert model_device(model) == torch.device("cpu")
    frame = synthetic_frames(model.inputs, 1, 16, 16)[0]
    with torch.no_grad():
        out = FrameLoop(model)(frame)
    assert out.shape == (1, 3, 16, 16) and out.device == model_device(model)
