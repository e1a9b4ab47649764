"""rtdenoise.ops: every custom op declared once (`OpSpec`), free of torch and onnx.

Each module of this package declares one op as `SPEC`; `SPECS` maps op names to them,
found by scanning the package (no hand-kept list), then the modules of other packages that the
entry points of group `rtdenoise.ops` name (`plugins`; docs/your-own-model.md). The forms of an
op live in modules of the same name in `rtdenoise.models.ops` (torch), `rtdenoise.export.ops`
(ONNX function body) and `rtdenoise.runtime.kernels` (fast kernel), or in the modules of the
matching entry-point groups. See docs/architecture.md, "Adding an op".
"""

from __future__ import annotations

import warnings

from . import plugins
from .discover import import_submodules
from .spec import DOMAIN, DOMAIN_VERSION, Arg, OpSpec, snake_case

SPECS: dict[str, OpSpec] = {}


def _register_specs() -> None:
    """Fill `SPECS` from this package's modules, then the entry points' (an op name that is
    taken already is refused with a warning naming both modules)."""
    origin: dict[str, str] = {}
    in_tree = import_submodules(__name__)
    for module in [*in_tree, *plugins.load_modules(plugins.OPS)]:
        spec = getattr(module, "SPEC", None)
        if not isinstance(spec, OpSpec):
            continue
        if spec.name in SPECS and SPECS[spec.name] is not spec:
            warnings.warn(
                f"op {spec.name!r} of {module.__name__} is left out: {origin[spec.name]} "
                "declares it already",
                RuntimeWarning,
                stacklevel=2,
            )
            continue
        SPECS[spec.name], origin[spec.name] = spec, module.__name__


def register_spec(spec: OpSpec) -> OpSpec:
    """Add `spec` to `SPECS` (what an op module of code that is not installed calls, so that
    its forms find it); the same spec again is a no-op, another one of a taken name ValueError."""
    if SPECS.get(spec.name, spec) is not spec:
        raise ValueError(f"op name {spec.name!r} is taken by another spec")
    SPECS[spec.name] = spec
    return spec


_register_specs()


def get_spec(name: str) -> OpSpec:
    """The spec of op `name`; KeyError listing the known ops otherwise."""
    try:
        return SPECS[name]
    except KeyError:
        raise KeyError(f"unknown rtdenoise op {name!r}; known: {sorted(SPECS)}") from None


__all__ = [
    "DOMAIN",
    "DOMAIN_VERSION",
    "SPECS",
    "Arg",
    "OpSpec",
    "get_spec",
    "import_submodules",
    "register_spec",
    "snake_case",
]
