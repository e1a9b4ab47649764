"""The packaging facts the README promises (pyproject.toml): a base install without a deep
learning framework or numba, extras by role, the numba kernels only where their wheels exist."""

from __future__ import annotations

import sys
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement

import rtdenoise

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
BASE = {Requirement(r).name.lower(): Requirement(r) for r in PROJECT["dependencies"]}
EXTRAS = PROJECT["optional-dependencies"]
NUMBA = {Requirement(r).name.lower(): Requirement(r) for r in EXTRAS["numba"]}


def test_installed_version_is_the_package_version():
    assert metadata.version("rtdenoise") == rtdenoise.__version__


def test_base_install_has_no_framework_and_extras_by_role():
    """The base dependencies are the runtime's; numba, torch, onnx, mitsuba come with extras,
    numba with every extra that imports the PyTorch models (export, train, bench) and test."""
    assert set(BASE) == {"numpy", "onnxruntime", "openexr", "typer", "rich", "tomli"}
    extras = EXTRAS
    assert set(extras) == {"numba", "export", "train", "data", "bench", "cluster", "all", "test"}
    names = {e: {Requirement(r).name for r in reqs} for e, reqs in extras.items()}
    assert set(NUMBA) == {"numba", "onnxruntime-extensions"}
    assert {"torch", "onnx", "onnxscript"} <= names["export"]
    assert names["train"] == {"rtdenoise"} and names["data"] == {"mitsuba"}
    assert names["cluster"] == {"ray"}
    for extra in ("export", "test", "all"):
        assert "numba" in Requirement(extras[extra][0]).extras, extra
    assert extras["train"] == ["rtdenoise[export]"] and "rtdenoise[export]" in extras["bench"]
    torch = next(Requirement(r) for r in extras["export"] if r.startswith("torch"))
    assert all(s.operator == ">=" for s in torch.specifier)  # a newer torch is never downgraded
    assert isinstance(PROJECT["license"], str)  # SPDX expression, not the deprecated table
    assert "/demo-out/" in (ROOT / ".gitignore").read_text().splitlines()


ENV = {"python_version": "3.11", "sys_platform": "linux", "platform_machine": "x86_64"}


@pytest.mark.parametrize(
    "env, fast",
    [
        ({}, True),
        ({"platform_machine": "aarch64"}, True),
        ({"python_version": "3.13", "sys_platform": "win32", "platform_machine": "AMD64"}, True),
        ({"sys_platform": "darwin", "platform_machine": "arm64"}, True),
        ({"sys_platform": "darwin", "platform_machine": "x86_64"}, False),  # no numba wheel
        ({"sys_platform": "win32", "platform_machine": "ARM64"}, False),  # no ortx wheel
        ({"python_version": "3.14"}, False),  # no ortx wheel
        ({"platform_machine": "armv7l"}, False),
    ],
)
def test_numba_kernels_only_where_both_have_wheels(env, fast):
    for name in ("numba", "onnxruntime-extensions"):
        assert NUMBA[name].marker.evaluate(ENV | env) is fast, name
    assert BASE["tomli"].marker.evaluate(ENV | {"python_version": "3.10"})
    assert not BASE["tomli"].marker.evaluate(ENV)


def test_every_family_module_is_declared_an_entry_point():
    """The shipped families are found only through their entry points (docs/your-own-model.md):
    a module of models/families/ without one would be silently missing."""
    from rtdenoise.models.registry import families

    declared = PROJECT["entry-points"]["rtdenoise.families"]
    modules = {p.stem for p in (ROOT / "models" / "families").glob("*.py") if p.stem != "__init__"}
    assert {v.split(":")[0].rsplit(".", 1)[1] for v in declared.values()} == modules
    assert set(declared) <= set(families())
