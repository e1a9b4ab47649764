"""rtdenoise.runtime imports and runs a model with torch blocked (docs/architecture.md)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

from contract_models import ema_model
from without_modules import without

SCRIPT = without("torch") + textwrap.dedent(  # any `import torch` now raises ImportError
    """
    import json, sys
    import numpy as np
    import rtdenoise.runtime
    from rtdenoise.runtime import Denoiser, read_exr, write_exr  # noqa: F401

    den = Denoiser(sys.argv[1])  # default options: fast kernels on, io binding
    rng = np.random.default_rng(0)
    outs = [den.process({"color": rng.random((3, 16, 16), dtype=np.float32),
                         "albedo": np.ones((3, 16, 16), np.float32)}) for _ in range(3)]
    print(json.dumps({
        "torch": repr(sys.modules.get("torch", "absent")),
        "torch_submodules": sorted(m for m in sys.modules if m.startswith("torch.")),
        "shapes": [list(o.shape) for o in outs],
        "finite": bool(all(np.isfinite(o).all() for o in outs)),
        "frame_index": den.frame_index,
    }))
    """
)


def test_runtime_runs_without_torch(tmp_path) -> None:
    model = tmp_path / "ema.onnx"
    model.write_bytes(ema_model())
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", SCRIPT, str(model)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["torch"] == "None"  # still blocked: nothing imported torch for real
    assert result["torch_submodules"] == []
    assert result["shapes"] == [[3, 16, 16]] * 3
    assert result["finite"] and result["frame_index"] == 3


SCRIPT_INSTALLED = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    from rtdenoise.runtime import Denoiser

    den = Denoiser(sys.argv[1])  # default: fast kernels registered (onnxruntime-extensions)
    for _ in range(3):
        den.process({"color": np.ones((3, 8, 8), np.float32),
                     "albedo": np.ones((3, 8, 8), np.float32)})
    print(json.dumps({"torch_loaded": sorted(m for m in sys.modules if m.split(".")[0] == "torch"),
                      "fast_kernels": den.fast_kernels}))
    """
)


def test_runtime_leaves_installed_torch_alone(tmp_path) -> None:
    """With torch installed, using the runtime (fast kernels included) still never imports it."""
    model = tmp_path / "ema.onnx"
    model.write_bytes(ema_model())
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", SCRIPT_INSTALLED, str(model)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["torch_loaded"] == []
