"""Family name -> model class; `build_model` is the one constructor.

Every module of `rtdenoise.models.families` is imported on first use; each registers its
model class with `@register_family` (models.base), so adding a family edits no list here.
"""

from __future__ import annotations

import functools

from rtdenoise.ops import import_submodules

from .base import FAMILIES, DenoiserModel


@functools.cache
def _discover() -> dict[str, type[DenoiserModel]]:
    import_submodules("rtdenoise.models.families")
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


def default_config(family: str) -> dict:
    """The JSON-able default config of `family`."""
    return family_class(family).config_class.from_dict(None).to_dict()


def build_model(family: str, config: dict | None = None) -> DenoiserModel:
    """A fresh (randomly initialised) model of `family`; `config` overrides the defaults.

    Raises ValueError for an unknown family or unknown / invalid config keys.
    """
    cls = family_class(family)
    return cls(cls.config_class.from_dict(config))
