"""A denoiser and a filter op that live in the user's package (examples/your_own_model, the
tutorial of docs/your-own-model.md): installed with pip into a folder of its own, found through
their entry points, trained, exported and run from the command line with no change to
rtdenoise, the runtime with torch blocked; the op passes the generic form test."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from rtdenoise.models.checkpoint import CheckpointError, load_checkpoint
from rtdenoise.shipped import sample_sequences

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "examples" / "your_own_model"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """blend-kpn installed (not editable) into a folder of its own."""
    pytest.importorskip("setuptools")  # the build runs without isolation: no download
    target = tmp_path_factory.mktemp("site")
    source = tmp_path_factory.mktemp("src") / "blend_kpn_src"
    shutil.copytree(PACKAGE, source)  # pip builds in the source folder: keep the repo clean
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
         "--target", str(target), str(source)],
        check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    return target


def run(site: Path, code: str, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(site)) if site else dict(os.environ)
    return subprocess.run(
        [sys.executable, "-W", "ignore", "-c", code, *args],
        capture_output=True, text=True, timeout=600, env=env, cwd=cwd,
    )  # fmt: skip


CLI = "import sys; from rtdenoise.cli.{0} import main; sys.argv[0] = 'denoise-{0}'; main()"
NO_TORCH = "import sys; sys.modules['torch'] = None; "


def test_train_export_and_run_a_family_and_op_from_outside(site, tmp_path):
    seq = sample_sequences()[0]
    ckpt, onnx_file, out = tmp_path / "kpn.pt", tmp_path / "kpn.onnx", tmp_path / "out"
    train = run(site, CLI.format("train"), str(seq), "-o", str(ckpt), "--family", "blendkpn",
                "--steps", "3", "--crop", "32", "--frames", "2", "--batch", "1",
                "--config", '{"width": 4}', "--no-progress")  # fmt: skip
    assert train.returncode == 0, train.stderr[-2000:]
    export = run(site, CLI.format("export"), str(ckpt), "-o", str(onnx_file), "--frames", "3",
                 "--size", "32")  # fmt: skip
    assert export.returncode == 0, export.stderr[-2000:]
    assert "NeighbourBlend x2" in export.stdout and onnx_file.is_file()
    frames = str(seq / "frame_000[0-2].exr")
    denoise = run(site, NO_TORCH + CLI.format("run"), frames, "-o", str(out), "--model",
                  str(onnx_file))  # fmt: skip
    assert denoise.returncode == 0, denoise.stderr[-2000:]
    assert sorted(p.name for p in out.glob("*.exr")) == [f"frame_000{i}.exr" for i in range(3)]
    calls = run(site, NO_TORCH + """
import json, numpy as np
from rtdenoise.runtime import Denoiser, bridge
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
den = Denoiser(sys.argv[1])
outs = [den.process(f) for f in synthetic_frames(den.required_buffers, 2, 24, 24)]
print(json.dumps({"calls": bridge.CALLS["NeighbourBlend"], "bridge": den.bridge,
                  "finite": bool(all(np.isfinite(o).all() for o in outs))}))
""", str(onnx_file))  # fmt: skip
    assert calls.returncode == 0, calls.stderr[-2000:]
    assert json.loads(calls.stdout) == {"calls": 4, "bridge": "native", "finite": True}
    # where the family is not installed, its checkpoint says what to install or import
    with pytest.raises(
        CheckpointError,
        match=r"family 'blendkpn' is not registered here \(it "
        r"came from module blend_kpn.model, distribution blend-kpn 0.1.0\)",
    ):
        load_checkpoint(ckpt)


def test_the_users_op_passes_the_generic_form_test(site):
    code = f"""
import sys
sys.path.insert(0, {str(ROOT / "tests")!r})
import numpy as np
from op_forms import all_forms, assert_forms_agree
from rtdenoise.ops import get_spec
spec = get_spec("NeighbourBlend")
rng = np.random.default_rng(0)
for shape in [(1, 3, 5, 7), (2, 4, 9, 6)]:
    inputs = spec.example_inputs(shape, {{}}, rng)
    assert_forms_agree(all_forms("NeighbourBlend", inputs, {{}}))
print("ok")
"""
    proc = run(site, code)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "ok"


def test_family_module_for_code_that_is_not_installed(tmp_path):
    """`--family-module blend_kpn.model`, found from the working folder: training runs."""
    seq = sample_sequences()[0]
    ckpt = tmp_path / "kpn.pt"
    proc = run(None, CLI.format("train"), str(seq), "-o", str(ckpt), "--family", "blendkpn",
               "--family-module", "blend_kpn.model", "--steps", "2", "--crop", "16", "--frames",
               "2", "--batch", "1", "--config", '{"width": 4}', "--no-progress",
               cwd=PACKAGE)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    unknown = run(None, CLI.format("train"), str(seq), "-o", str(ckpt), "--family-module",
                  "no_such_module_here", cwd=tmp_path)  # fmt: skip
    assert unknown.returncode == 2
    assert "--family-module no_such_module_here: cannot import it" in unknown.stderr
