"""Release metadata (issue 28): the licence, the project metadata, the changelog, and one
version that the package, its metadata and every command agree on."""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from importlib import import_module, metadata
from pathlib import Path

import pytest
from typer.testing import CliRunner

import rtdenoise
from rtdenoise._version import __version__ as written_version

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
PROJECT = PYPROJECT["project"]
COMMANDS = ("export", "run", "train", "render", "bench")


def test_the_version_is_written_once_and_everyone_reads_it():
    assert "version" in PROJECT["dynamic"] and "version" not in PROJECT
    dynamic = PYPROJECT["tool"]["setuptools"]["dynamic"]["version"]
    assert dynamic == {"attr": "rtdenoise._version.__version__"}
    assert rtdenoise.__version__ == written_version == metadata.version("rtdenoise")
    assert re.fullmatch(r"\d+\.\d+\.\d+", written_version)
    sources = [
        p
        for p in ROOT.rglob("*.py")
        if not {".venv", "build", ".git"} & set(p.relative_to(ROOT).parts)
    ]
    assigned = [p for p in sources if re.search(r"^__version__\s*=", p.read_text(), re.M)]
    assert assigned == [ROOT / "rtdenoise" / "_version.py"]


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_reports_that_version(command):
    res = CliRunner().invoke(import_module(f"rtdenoise.cli.{command}").app, ["--version"])
    assert res.exit_code == 0, res.output
    assert res.output.split()[:2] == ["rtdenoise", written_version]


def test_licence_and_metadata():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "rtdenoise developers" in text
    assert PROJECT["license"] == "MIT" and PROJECT["license-files"] == ["LICENSE"]
    assert PROJECT["authors"] == [{"name": "rtdenoise developers"}]
    assert PROJECT["keywords"]
    classifiers = PROJECT["classifiers"]
    # An SPDX `license` forbids License :: classifiers (setuptools >= 77 refuses both).
    assert not [c for c in classifiers if c.startswith("License ::")]
    versions = {c.rsplit(" ", 1)[1] for c in classifiers if re.search(r":: 3\.\d+$", c)}
    assert versions == {"3.10", "3.11", "3.12", "3.13"}
    # The installed metadata carries them (an editable install too; not a stale
    # rtdenoise.egg-info an older build left in the checkout, found first from its root).
    installed = [
        d for d in metadata.distributions(name="rtdenoise") if Path(d.locate_file("")) != ROOT
    ]
    assert installed, "rtdenoise is not installed"
    meta = installed[0].metadata
    assert meta["License-Expression"] == "MIT" and meta["Author"] == "rtdenoise developers"


def test_changelog_has_an_entry_for_this_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    first = re.search(r"^## (\S+)", text, re.M)
    assert first is not None and first.group(1) == written_version
    for topic in ("afn", "wskp", "nbg", "affinity", "crossreg", "denoise-export", "MIT"):
        assert topic in text, topic


CIBW = PYPROJECT["tool"]["cibuildwheel"]


def test_cibuildwheel_builds_the_supported_platforms_with_every_extension():
    assert CIBW["build"].split() == ["cp310-*", "cp311-*", "cp312-*", "cp313-*"]
    assert CIBW["skip"] == "*-musllinux_*"  # onnxruntime publishes no musllinux wheels
    assert CIBW["linux"]["archs"] == ["x86_64", "aarch64"]
    assert CIBW["macos"]["archs"] == ["arm64"] and CIBW["windows"]["archs"] == ["AMD64"]
    for where in (CIBW, CIBW["macos"]):
        assert where["environment"]["RTDENOISE_REQUIRE_EXTENSIONS"] == "1"
    assert "scripts/check_wheel.py" in CIBW["test-command"]
    text = (ROOT / "pyproject.toml").read_text()
    section = text[text.index("[tool.cibuildwheel]") : text.index("[tool.pytest.ini_options]")]
    assert "_ort_bridge" not in section  # extensions come from setup.py, never listed here


@pytest.mark.parametrize("required", ["1", None])
def test_a_release_build_makes_every_extension_required(required):
    """setup.py's Extensions as setup() receives them: none optional for a release."""
    code = (
        "import setuptools; "
        "setuptools.setup = lambda **kw: print([e.optional for e in kw['ext_modules']]); "
        "exec(compile(open('setup.py').read(), 'setup.py', 'exec'))"
    )
    env = {k: v for k, v in os.environ.items() if k != "RTDENOISE_REQUIRE_EXTENSIONS"}
    if required:
        env["RTDENOISE_REQUIRE_EXTENSIONS"] = required
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr
    optional = ast.literal_eval(proc.stdout.strip())  # a printed list of bools
    assert optional and all(o is (required is None) for o in optional)


def test_check_wheel_finds_every_extension_setup_py_declares(tmp_path):
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        from check_wheel import declared_extensions
    finally:
        sys.path.remove(str(ROOT / "scripts"))
    assert declared_extensions(ROOT / "setup.py") == [
        "rtdenoise.runtime.bridge._ort_bridge",
        "rtdenoise.runtime.bridge.rtdenoise_ops",
    ]
    other = tmp_path / "setup.py"  # a second one, however it is spelled
    other.write_text(
        "from setuptools import Extension\nimport setuptools\n"
        "A = Extension('pkg.a', ['a.c'])\nB = setuptools.Extension(name='pkg.b', sources=[])\n"
    )
    assert declared_extensions(other) == ["pkg.a", "pkg.b"]


README = (ROOT / "README.md").read_text()


def test_readme_states_the_gpu_status():
    line = next(p for p in README.split("\n\n") if p.startswith("**GPU: status"))
    assert "Nothing in this project has run on a GPU yet" in line
    assert "`--provider cuda`, `tensorrt`" in line and "never been run by" in line
    assert "tests/test_gpu.py" in line and "have not yet run" in line
    assert "OIDN" not in line  # the comparison table is measured elsewhere


def test_readme_buffer_table_is_what_each_demo_reads():
    """The caveats' table of buffers, row by row, against each shipped model's inputs."""
    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.contract import BUFFER_CHANNELS, SAMPLES

    known = set(BUFFER_CHANNELS) | {SAMPLES}
    table = README[README.index("| model | buffers |") :].split("\n\n")[0].splitlines()[2:]
    seen = set()
    for row in table:
        _, models, buffers, _ = row.split("|")
        listed = set(re.findall(r"`(\w+)`", buffers)) & known
        for family in re.findall(r"`(\w+)`", models):
            seen.add(family)
            needs = set(Denoiser(f"demo:{family}", fast_kernels=False).required_buffers)
            assert needs <= listed, family
            if SAMPLES not in needs:  # a per-sample model's row also names the features
                assert listed == needs, family
    assert seen == {"afn", "wskp", "nbg", "affinity", "crossreg"}
