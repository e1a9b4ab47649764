"""Where numba has no wheel, the runtime runs the custom ops' portable ONNX bodies, with one
warning, and denoise-run still works (pyproject.toml installs the fast kernels only where numba
and onnxruntime-extensions have wheels); without onnxruntime-extensions the native bridge still
runs the fast kernels."""

from __future__ import annotations

import subprocess
import sys

import pytest
from progress_lines import other_lines

from rtdenoise.shipped import sample_sequences

SCRIPT = """
import sys
sys.modules[sys.argv[1]] = None  # as if it had no wheel for this platform
from rtdenoise.cli.run import main
sys.argv[1:] = sys.argv[2:]
main()
"""


@pytest.mark.parametrize("missing", ["onnxruntime_extensions", "numba"])
def test_denoise_run_without_a_kernel_library(tmp_path, missing):
    seq = sample_sequences()[0]
    args = [str(seq / "frame_000[0-2].exr"), "-o", str(tmp_path), "--model", "demo:wskp"]
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, missing, *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    lines = other_lines(proc.stderr)
    if missing == "onnxruntime_extensions":  # the native bridge needs none of it
        assert lines == []
    else:
        assert len(lines) == 1 and lines[0].startswith("warning: fast kernels unavailable"), lines
        assert missing in lines[0] and "portable ONNX bodies" in lines[0]
    assert sorted(p.name for p in tmp_path.glob("*.exr")) == [f"frame_000{i}.exr" for i in range(3)]
    assert "PSNR" in proc.stdout
