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


def test_the_checker_sees_relative_and_nested_imports(tmp_path):
    assert "rtdenoise.runtime.contract" in {n for _, n in imports_of(ROOT / "models/base.py")}
    names = {n for _, n in imports_of(ROOT / "models/families/afn.py")}
    assert {"rtdenoise.models.accumulation", "rtdenoise.models.ops.softmax_kernel_apply"} <= names
