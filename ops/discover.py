"""Find the modules of a package: how ops, op forms and families register where defined."""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType


def import_submodules(package: str) -> list[ModuleType]:
    """Import every public module of `package` (names not starting with '_'), sorted by name.

    A module registers what it defines when imported (an `OpSpec`, a decorated torch form,
    function body, fast kernel or model family), so that no registry is edited by hand.
    """
    pkg = importlib.import_module(package)
    names = sorted(
        info.name for info in pkgutil.iter_modules(pkg.__path__) if not info.name.startswith("_")
    )
    return [importlib.import_module(f"{package}.{name}") for name in names]
