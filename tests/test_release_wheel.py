"""The Linux release wheel, end to end (issue 28): scripts/build_release_wheel.sh builds it
from a copy of this checkout with every extension required, repairs it with auditwheel to a
manylinux tag, passes `twine check` (with the sdist), installs it in a fresh venv with binary
wheels only and no compiler (CC=false), and there scripts/check_wheel.py finds every
Extension of setup.py compiled in, neither torch nor numba installed (no extra asked for),
every shipped demo on the C++ library, and `denoise-run --demo` passing.

Part of CI's plain `python -m pytest -q`: 2-6 minutes on 2 shared cores (5.4 measured with
two other jobs beside it), building the wheel (the C++ library at -O3) and pip installing the
dependencies into the fresh venv; no numba there to install or compile. Needs a package index
(PyPI): skipped without one.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "build_release_wheel.sh"
OFFLINE = ("NewConnectionError", "Temporary failure in name resolution", "Network is unreachable")

pytestmark = [
    pytest.mark.skipif(not sys.platform.startswith("linux"), reason="builds the Linux wheel"),
]


def test_release_wheel_builds_repairs_installs_without_a_compiler_and_runs_the_demo(tmp_path):
    out = tmp_path / "dist"
    proc = subprocess.run(
        ["bash", str(SCRIPT), str(out)],
        env={**os.environ, "PYTHON": sys.executable},
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if proc.returncode != 0 and any(s in proc.stderr for s in OFFLINE):
        pytest.skip("no package index reachable: the fresh venv needs one (CI has PyPI)")
    assert proc.returncode == 0, proc.stderr[-4000:]
    wheels = sorted(p.name for p in out.glob("*.whl"))
    tag = f"cp{sys.version_info.major}{sys.version_info.minor}"
    assert len(wheels) == 1 and f"-{tag}-{tag}-manylinux" in wheels[0], wheels
    assert len(list(out.glob("rtdenoise-*.tar.gz"))) == 1  # the sdist beside it
    assert proc.stderr.count("PASSED") == 2  # twine check --strict of both
    assert proc.stdout.strip().splitlines()[-1] == "check_wheel: ok", proc.stdout
    assert "over 3 sequences: mean PSNR" in proc.stdout
