"""Family name -> model class and default config; `build_model` is the one constructor."""

from __future__ import annotations

from collections.abc import Callable

from .afn import AFN, AFNConfig
from .base import DenoiserModel
from .wskp import WSKP, WSKPConfig

# family -> (model class, config parser: dict | None -> config object with `to_dict()`)
FAMILIES: dict[str, tuple[type[DenoiserModel], Callable[[dict | None], object]]] = {
    "afn": (AFN, AFNConfig.from_dict),
    "wskp": (WSKP, WSKPConfig.from_dict),
}


def families() -> list[str]:
    """Registered family names, sorted."""
    return sorted(FAMILIES)


def _lookup(family: str) -> tuple[type[DenoiserModel], Callable[[dict | None], object]]:
    try:
        return FAMILIES[family]
    except KeyError:
        raise ValueError(f"unknown model family {family!r}; known: {families()}") from None


def default_config(family: str) -> dict:
    """The JSON-able default config of `family`."""
    _, parse = _lookup(family)
    return parse(None).to_dict()


def build_model(family: str, config: dict | None = None) -> DenoiserModel:
    """A fresh (randomly initialised) model of `family`; `config` overrides the defaults.

    Raises ValueError for an unknown family or unknown / invalid config keys.
    """
    cls, parse = _lookup(family)
    return cls(parse(config))
