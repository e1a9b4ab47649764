"""Family name -> model class; `build_model` is the one constructor.

Families are found through the entry points of group `rtdenoise.families` (`name =
"module:Class"`, a class decorated `@register_family`): rtdenoise's own five are declared there
in its pyproject.toml exactly as a user's package declares its own (docs/your-own-model.md).
Code that is not installed as a package joins with `load_family_module` (`--family-module` of
`denoise-train` / `denoise-export`). Where each family came from is recorded in its checkpoints
(`family_source`), so that a checkpoint whose family is missing says how to make it importable.
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import sys
import warnings
from pathlib import Path
from typing import Any

from rtdenoise.ops import plugins

from .base import FAMILIES, DenoiserModel

_SOURCES: dict[str, dict[str, Any]] = {}  # family -> where it came from


@functools.cache
def _discover() -> dict[str, type[DenoiserModel]]:
    for ep, cls in plugins.load_objects(plugins.FAMILIES):
        if not (isinstance(cls, type) and issubclass(cls, DenoiserModel)) or cls.family != ep.name:
            warnings.warn(
                f"entry point {ep.name} = {ep.value!r} of group {plugins.FAMILIES!r} is left "
                f"out: it must name a DenoiserModel class whose family is {ep.name!r}",
                RuntimeWarning,
                stacklevel=3,
            )
            continue
        _SOURCES.setdefault(
            cls.family,
            {
                "module": cls.__module__,
                "entry_point": f"{ep.name} = {ep.value}",
                "distribution": plugins.distribution_of(ep),
            },
        )
    return FAMILIES


def families() -> list[str]:
    """Registered family names, sorted."""
    return sorted(_discover())


def family_class(family: str) -> type[DenoiserModel]:
    """The model class of `family`; ValueError listing the known families otherwise."""
    try:
        return _discover()[family]
    except KeyError:
        raise ValueError(f"unknown model family {family!r}; known: {families()}") from None


def family_source(family: str) -> dict[str, Any]:
    """Where `family` came from: its module, and the entry point and distribution that declare
    it (None each for a family loaded with `load_family_module`)."""
    cls = family_class(family)
    return dict(
        _SOURCES.get(family, {"module": cls.__module__, "entry_point": None, "distribution": None})
    )


def load_family_module(spec: str) -> list[str]:
    """Import the module `spec` names, a dotted name (found from the working folder too, as
    `python -m` finds it) or a .py file, so that the families it defines register; returns the
    families it added. ValueError naming `spec` when it does not import."""
    before = set(_discover())
    try:
        if spec.endswith(".py"):
            path = Path(spec).resolve()
            if not path.is_file():
                raise ValueError(f"--family-module {spec}: no such file")
            name = f"_rtdenoise_family_{path.stem}"
            module_spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[name] = module
            module_spec.loader.exec_module(module)
        else:
            if "" not in sys.path and str(Path.cwd()) not in sys.path:
                sys.path.insert(0, str(Path.cwd()))
            importlib.import_module(spec)
    except ValueError:
        raise
    except Exception as exc:
        raise ValueError(
            f"--family-module {spec}: cannot import it ({type(exc).__name__}: {exc})"
        ) from exc
    return sorted(set(FAMILIES) - before)


def default_config(family: str) -> dict:
    """The JSON-able default config of `family`."""
    return family_class(family).config_class.from_dict(None).to_dict()


def build_model(family: str, config: dict | None = None) -> DenoiserModel:
    """A fresh (randomly initialised) model of `family`; `config` overrides the defaults.

    Raises ValueError for an unknown family or unknown / invalid config keys.
    """
    cls = family_class(family)
    return cls(cls.config_class.from_dict(config))
