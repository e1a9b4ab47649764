"""Suite-wide settings, applied before any test module imports torch."""

import os

# Idle OpenMP workers sleep instead of spinning: on a shared 2-core machine spinning made tiny
# torch ops hundreds of times slower (measured). libgomp reads this when torch loads.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
