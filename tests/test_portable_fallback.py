"""Where numba has no wheel, the runtime runs the custom ops' portable ONNX bodies, with one
warning, and denoise-run still works (pyproject.toml installs the fast kernels only where numba
and onnxruntime-extensions have wheels); without onnxruntime-extensions the native bridge still
runs the fast kernels; without numba a model the C++ library rtdenoise_ops holds (demo:wskp)
runs on it, with no warning (and with RTDENOISE_NATIVE_OPS=0 on the portable bodies)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from progress_lines import other_lines

from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.shipped import sample_sequences

SCRIPT = """
import sys
sys.modules[sys.argv[1]] = None  # as if it had no wheel for this platform
from rtdenoise.cli.run import main
sys.argv[1:] = sys.argv[2:]
main()
"""


@pytest.mark.parametrize(
    "missing, cpp", [("onnxruntime_extensions", "1"), ("numba", "1"), ("numba", "0")]
)
def test_denoise_run_without_a_kernel_library(tmp_path, missing, cpp):
    seq = sample_sequences()[0]
    args = [str(seq / "frame_000[0-2].exr"), "-o", str(tmp_path), "--model", "demo:wskp"]
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, missing, *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=os.environ | {native_cpp.ENV_SWITCH: cpp},
    )
    assert proc.returncode == 0, proc.stderr
    lines = other_lines(proc.stderr)
    if missing == "onnxruntime_extensions":  # the native bridge needs none of it
        assert lines == []
    elif cpp == "1" and native_cpp.available():  # the C++ library needs no numba
        assert lines == []
        assert "custom ops: native-cpp" in proc.stdout
    else:
        assert len(lines) == 1 and lines[0].startswith("warning: fast kernels unavailable"), lines
        assert missing in lines[0] and "portable ONNX bodies" in lines[0]
    assert sorted(p.name for p in tmp_path.glob("*.exr")) == [f"frame_000{i}.exr" for i in range(3)]
    assert "PSNR" in proc.stdout
