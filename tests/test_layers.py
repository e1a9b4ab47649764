"""What may import what (docs/architecture.md, "Layers"), checked on the source: every import
statement of every module, including imports inside functions."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# folder -> module prefixes it must never import
FORBIDDEN = {
    "ops": (
        "torch",
        "onnx",
        "onnxscript",
        "onnxruntime",
        "numba",
        "rtdenoise.models",
        "rtdenoise.export",
        "rtdenoise.runtime",
        "rtdenoise.cli",
        "rtdenoise.datagen",
    ),
    "runtime": (
        "torch",
        "onnx",
        "onnxscript",
        "rtdenoise.models",
        "rtdenoise.export",
        "rtdenoise.cli",
        "rtdenoise.datagen",
    ),
    "models": (
        "onnx",
        "onnxscript",
        "onnxruntime",
        "rtdenoise.export",
        "rtdenoise.cli",
        "rtdenoise.datagen",
    ),
    "export": ("rtdenoise.cli", "rtdenoise.datagen"),
    "datagen": ("torch", "rtdenoise.models", "rtdenoise.export", "rtdenoise.cli"),
}


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in `path` (relative ones resolved)."""
    package = ["rtdenoise", *path.parent.relative_to(ROOT).parts]
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(package)[:None].split(".")
                base = base[: len(base) - node.level + 1]
                name = ".".join([*base, node.module] if node.module else base)
            else:
                name = node.module or ""
            found.append((node.lineno, name))
    return found


def _hits(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


@pytest.mark.parametrize("folder", sorted(FORBIDDEN))
def test_layer_imports(folder):
    files = sorted((ROOT / folder).rglob("*.py"))
    assert files
    bad = [
        f"{p.relative_to(ROOT)}:{line} imports {name}"
        for p in files
        for line, name in imports_of(p)
        if _hits(name, FORBIDDEN[folder])
    ]
    assert bad == []


# The three wings of runtime/ (docs/architecture.md, "Runtime"): files -> what they may import
# of rtdenoise. The host wing (what a host embeds) and the bridge wing never import the
# sequence tooling; the bridge wing (with the kernels it registers) imports only itself and the
# op specs; onnxruntime-extensions is imported by its bridge alone.
HOST = sorted(p for p in (ROOT / "runtime").glob("*.py") if p.name != "__init__.py")
BRIDGE = sorted(
    [*(ROOT / "runtime/bridge").rglob("*.py"), *(ROOT / "runtime/kernels").rglob("*.py")]
)
SEQUENCES = "rtdenoise.runtime.sequences"


def _rtdenoise_imports(paths: list[Path]) -> list[tuple[Path, int, str]]:
    return [
        (p, line, name)
        for p in paths
        for line, name in imports_of(p)
        if name == "rtdenoise" or name.startswith("rtdenoise.")
    ]


def test_host_wing_never_imports_the_sequence_tooling():
    assert len(HOST) >= 10
    bad = [
        f"{p.name}:{n} imports {m}"
        for p, n, m in _rtdenoise_imports(HOST)
        if _hits(m, (SEQUENCES,))
    ]
    assert bad == []


def test_bridge_wing_imports_only_itself_and_the_op_specs():
    allowed = ("rtdenoise.ops", "rtdenoise.runtime.bridge", "rtdenoise.runtime.kernels")
    assert len(BRIDGE) >= 10
    bad = [
        f"{p.relative_to(ROOT)}:{n} imports {m}"
        for p, n, m in _rtdenoise_imports(BRIDGE)
        if not _hits(m, allowed)
    ]
    assert bad == []


def test_onnxruntime_extensions_is_imported_by_its_bridge_alone():
    users = {
        p.relative_to(ROOT).as_posix()
        for folder in ("runtime", "cli", "models", "export", "ops", "datagen")
        for p in (ROOT / folder).rglob("*.py")
        for _, name in imports_of(p)
        if _hits(name, ("onnxruntime_extensions",))
    }
    assert users == {"runtime/bridge/extensions.py"}


def test_the_checker_sees_relative_and_nested_imports(tmp_path):
    assert "rtdenoise.runtime.contract" in {n for _, n in imports_of(ROOT / "models/base.py")}
    names = {n for _, n in imports_of(ROOT / "models/families/afn.py")}
    assert {"rtdenoise.models.accumulation", "rtdenoise.models.ops.softmax_kernel_apply"} <= names
