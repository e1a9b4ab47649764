"""`torch_device`: a device name from a command line checked before any work starts."""

from __future__ import annotations

import torch


class DeviceError(ValueError):
    """The device named cannot be used here (says why)."""


def torch_device(name: str) -> torch.device:
    """`torch.device(name)` after checking that it exists: ``cpu``, ``cuda`` or ``cuda:N``
    (``mps`` where PyTorch has it)."""
    try:
        device = torch.device(name)
    except RuntimeError as exc:
        raise DeviceError(f"unknown device {name!r}: expected cpu, cuda or cuda:N") from exc
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise DeviceError(
                f"device {name!r}: this PyTorch ({torch.__version__}) has no usable CUDA "
                "device (a CPU build, or no GPU / driver); use --device cpu"
            )
        count = torch.cuda.device_count()
        if device.index is not None and device.index >= count:
            raise DeviceError(f"device {name!r}: only {count} CUDA device(s) here")
    elif device.type == "mps" and not torch.backends.mps.is_available():
        raise DeviceError(f"device {name!r}: MPS is not available here; use --device cpu")
    elif device.type not in ("cpu", "cuda", "mps"):
        raise DeviceError(f"unsupported device {name!r}: expected cpu, cuda or cuda:N")
    return device


def model_device(model: torch.nn.Module) -> torch.device:
    """Where `model`'s parameters (or buffers) live; CPU for a model with neither."""
    for tensor in (*model.parameters(), *model.buffers()):
        return tensor.device
    return torch.device("cpu")
