"""Suite-wide settings, applied before any test module imports torch; the `slow` marker."""

import os

import pytest

# Idle OpenMP workers sleep instead of spinning: on a shared 2-core machine spinning made tiny
# torch ops hundreds of times slower (measured). libgomp reads this when torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

RUN_SLOW_ENV = "RTDENOISE_RUN_SLOW"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--run-slow",
        action="store_true",
        help=f"also run the tests marked slow (or set {RUN_SLOW_ENV}=1)",
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """`slow` tests (minutes: a release wheel built and installed afresh) are skipped unless
    asked for, so CI's plain `python -m pytest -q` stays within its time."""
    if config.getoption("--run-slow") or os.environ.get(RUN_SLOW_ENV) == "1":
        return
    skip = pytest.mark.skip(reason=f"slow: run with --run-slow or {RUN_SLOW_ENV}=1")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
