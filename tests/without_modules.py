"""Python run in a fresh interpreter as if some modules were not installed."""

from __future__ import annotations


def without(*modules: str) -> str:
    """Source to run first: every `import <m>` of `modules` (their submodules too) then raises
    ModuleNotFoundError and `importlib.util.find_spec(m)` returns None, as for a module that
    is not installed."""
    return "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in modules)
