"""Seeds: one well-mixed integer from a tuple of integers (numpy only)."""

from __future__ import annotations

import numpy as np


def derive_seed(*values: int) -> int:
    """A well-mixed 31-bit seed from integers (stable across runs and platforms)."""
    return int(np.random.SeedSequence([int(v) for v in values]).generate_state(1)[0] >> 1)
