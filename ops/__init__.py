"""rtdenoise.ops: every custom op declared once (`OpSpec`), free of torch and onnx.

Each module of this package declares one op as `SPEC`; `SPECS` maps op names to them,
found by scanning the package (no hand-kept list). The forms of an op live in modules of the
same name in `rtdenoise.models.ops` (torch), `rtdenoise.export.ops` (ONNX function body) and
`rtdenoise.runtime.kernels` (fast kernel). See docs/architecture.md, "Adding an op".
"""

from __future__ import annotations

from .discover import import_submodules
from .spec import DOMAIN, DOMAIN_VERSION, Arg, OpSpec, snake_case

SPECS: dict[str, OpSpec] = {
    module.SPEC.name: module.SPEC
    for module in import_submodules(__name__)
    if isinstance(getattr(module, "SPEC", None), OpSpec)
}


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
    "snake_case",
]
