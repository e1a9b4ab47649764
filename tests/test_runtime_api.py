"""The public runtime API (`from rtdenoise.runtime import ...`) and the package's layout: the
names a host imports stay as they are, and a checkout imports as it is laid out."""

from __future__ import annotations

import ast
import inspect
import os
import subprocess
import sys
import sysconfig
from pathlib import Path

import rtdenoise
import rtdenoise.runtime

ROOT = Path(__file__).resolve().parent.parent

PUBLIC = {
    "Contract": "class",
    "ContractError": "class",
    "Denoiser": "class",
    "Frame": "class",
    "InputError": "class",
    "Layout": "class",
    "StateSpec": "class",
    "find_frames": "function",
    "get_layout": "function",
    "iter_sequence": "function",
    "load_layout": "function",
    "parse_contract": "function",
    "read_exr": "function",
    "read_frame": "function",
    "resolve_model": "function",
    "resolve_providers": "function",
    "write_exr": "function",
    "write_output": "function",
}


def test_public_names_are_the_listed_ones():
    assert set(rtdenoise.runtime.__all__) == set(PUBLIC)
    for name, kind in PUBLIC.items():
        value = getattr(rtdenoise.runtime, name)
        assert (inspect.isclass if kind == "class" else inspect.isfunction)(value), name


def test_denoiser_keeps_its_signature():
    params = inspect.signature(rtdenoise.runtime.Denoiser).parameters
    assert list(params) == [
        "model", "fast_kernels", "threads", "pin_threads", "spinning", "providers",
        "io_binding", "shared_arena", "learn", "learn_every", "relearn_at_cuts", "overrides",
        "layout",
    ]  # fmt: skip
    process = inspect.signature(rtdenoise.runtime.Denoiser.process).parameters
    assert list(process) == ["self", "buffers", "reset", "out", "channels_last"]
    reset = inspect.signature(rtdenoise.runtime.Denoiser.reset).parameters
    assert list(reset) == ["self", "learning"]


def test_setup_maps_the_same_folders_as_the_checkout():
    tree = ast.parse((ROOT / "setup.py").read_text())
    found = [
        ast.literal_eval(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign)
        and any(isinstance(t, ast.Name) and t.id == "SUBPACKAGES" for t in node.targets)
    ]
    assert found == [rtdenoise.SUBPACKAGES]
    assert all((ROOT / name / "__init__.py").is_file() for name in rtdenoise.SUBPACKAGES)


def test_an_uninstalled_checkout_imports_as_laid_out(tmp_path):
    """Without the install's mapping (no site hooks: the editable finder is absent), from the
    checkout's root `rtdenoise.<folder>` is the folder."""
    code = f"""
import sys
sys.path.append({sysconfig.get_paths()["purelib"]!r})  # the dependencies, not rtdenoise
import rtdenoise.runtime.sequences.metrics as m, rtdenoise.ops, rtdenoise.runtime.contract as c
print(m.__file__)
print(c.__file__)
"""
    proc = subprocess.run(
        [sys.executable, "-S", "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    files = [Path(line) for line in proc.stdout.split()]
    assert files == [ROOT / "runtime/sequences/metrics.py", ROOT / "runtime/contract.py"]


def test_the_checkout_root_defers_to_an_installed_copy(tmp_path):
    """From the root the checkout's rtdenoise/ comes first on sys.path; with a non-editable
    install on sys.path, every submodule (the version too) is the installed copy's (issue 28:
    `python -c "from rtdenoise.runtime import Denoiser"` there after `pip install .`)."""
    site = tmp_path / "site"
    (site / "rtdenoise" / "runtime").mkdir(parents=True)
    (site / "rtdenoise" / "__init__.py").write_text("")
    (site / "rtdenoise" / "_version.py").write_text('__version__ = "9.9.9"\n')
    (site / "rtdenoise" / "runtime" / "__init__.py").write_text("class Denoiser: pass\n")
    code = (
        "import rtdenoise, rtdenoise.runtime as r; from rtdenoise.runtime import Denoiser; "
        "print(rtdenoise.__file__, r.__file__, rtdenoise.__version__)"
    )
    env = {**os.environ, "PYTHONPATH": str(site)}
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    init, runtime, version = proc.stdout.split()
    assert Path(init) == ROOT / "rtdenoise" / "__init__.py"  # found first: the shadow
    assert Path(runtime) == site / "rtdenoise" / "runtime" / "__init__.py" and version == "9.9.9"
    # Without an install elsewhere (this editable venv) the checkout stays itself.
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert Path(proc.stdout.split()[1]) == ROOT / "runtime" / "__init__.py"
