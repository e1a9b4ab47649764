"""denoise-run's plain progress lines (stderr not a terminal, cli/progress.py), told apart
from its warnings and errors."""

from __future__ import annotations

import re

PROGRESS = re.compile(r"^(.+: frame \d+/\d+|compiling fast kernel \S+ .*|compiled fast kernel .*)$")


def is_progress(line: str) -> bool:
    return PROGRESS.match(line) is not None


def other_lines(stderr: str) -> list[str]:
    """The stderr lines that are not progress lines (warnings, errors)."""
    return [line for line in stderr.strip().splitlines() if line and not is_progress(line)]
