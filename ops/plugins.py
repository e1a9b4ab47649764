"""Code from outside rtdenoise, found through entry points: families, ops and their forms.

A package joins by declaring entry points in its pyproject.toml (docs/your-own-model.md):

    [project.entry-points."rtdenoise.families"]
    mykpn = "my_pkg.kpn:MyKPN"             # a model class decorated @register_family
    [project.entry-points."rtdenoise.ops"]
    my_ops = "my_pkg.ops"                  # a module (or package) declaring OpSpec `SPEC`s
    [project.entry-points."rtdenoise.ops.torch"]
    my_ops = "my_pkg.torch_ops"            # the @torch_op forms        (needs torch)
    [project.entry-points."rtdenoise.ops.onnx"]
    my_ops = "my_pkg.onnx_ops"             # the @function_body forms   (needs onnx)
    [project.entry-points."rtdenoise.ops.kernels"]
    my_ops = "my_pkg.kernels"              # the @fast_kernel forms     (runtime: no torch)

Each registry loads its own group when it is first used, so the runtime (which never imports
torch) loads only the specs and the kernels. rtdenoise's own five families are entry points of
the same group (pyproject.toml): there is one path for them and a user's.
"""

from __future__ import annotations

import importlib
import pkgutil
import warnings
from importlib import metadata
from types import ModuleType
from typing import Any

FAMILIES = "rtdenoise.families"
OPS = "rtdenoise.ops"
TORCH_FORMS = "rtdenoise.ops.torch"
ONNX_FORMS = "rtdenoise.ops.onnx"
KERNELS = "rtdenoise.ops.kernels"
GROUPS = (FAMILIES, OPS, TORCH_FORMS, ONNX_FORMS, KERNELS)


def entry_points(group: str) -> list[metadata.EntryPoint]:
    """The installed entry points of `group`, sorted by name (then value)."""
    return sorted(metadata.entry_points(group=group), key=lambda ep: (ep.name, ep.value))


def distribution_of(ep: metadata.EntryPoint) -> str | None:
    """'name version' of the distribution that declares `ep`, where known."""
    dist = getattr(ep, "dist", None)
    return f"{dist.metadata['Name']} {dist.version}" if dist is not None else None


def _load(ep: metadata.EntryPoint, group: str) -> Any:
    """`ep.load()`, or None with a warning naming it and its distribution when that fails (a
    broken plugin does not stop the others)."""
    try:
        return ep.load()
    except Exception as exc:
        where = distribution_of(ep) or "an unknown distribution"
        warnings.warn(
            f"entry point {ep.name} = {ep.value!r} of group {group!r} (from {where}) failed to "
            f"load and is left out: {type(exc).__name__}: {exc}",
            RuntimeWarning,
            stacklevel=3,
        )
        return None


def load_objects(group: str) -> list[tuple[metadata.EntryPoint, Any]]:
    """(entry point, the object it names) for every entry point of `group` that loads."""
    loaded = [(ep, _load(ep, group)) for ep in entry_points(group)]
    return [(ep, value) for ep, value in loaded if value is not None]


def load_modules(group: str) -> list[ModuleType]:
    """Every module the entry points of `group` name, a package with each of its public
    submodules (imported: each registers what it defines), in order, without repeats."""
    modules: dict[str, ModuleType] = {}
    for ep in entry_points(group):
        value = _load(ep, group)
        if not isinstance(value, ModuleType):
            if value is not None:
                warnings.warn(
                    f"entry point {ep.name} = {ep.value!r} of group {group!r} names "
                    f"{type(value).__name__} {value!r}; expected a module: left out",
                    RuntimeWarning,
                    stacklevel=2,
                )
            continue
        modules.setdefault(value.__name__, value)
        if hasattr(value, "__path__"):  # a package
            for info in sorted(pkgutil.iter_modules(value.__path__), key=lambda i: i.name):
                if not info.name.startswith("_"):
                    name = f"{value.__name__}.{info.name}"
                    modules.setdefault(name, importlib.import_module(name))
    return list(modules.values())


__all__ = [
    "FAMILIES",
    "GROUPS",
    "KERNELS",
    "ONNX_FORMS",
    "OPS",
    "TORCH_FORMS",
    "distribution_of",
    "entry_points",
    "load_modules",
    "load_objects",
]
