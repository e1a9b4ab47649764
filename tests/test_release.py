"""Release metadata (issue 28): the licence, the project metadata, the changelog, and one
version that the package, its metadata and every command agree on."""

from __future__ import annotations

import re
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
