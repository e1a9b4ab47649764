"""Process-wide memory tuning for per-frame processing of large buffers."""

from __future__ import annotations

import ctypes
import sys


def tune_allocator(threshold_bytes: int = 1 << 30) -> bool:
    """Serve blocks below `threshold_bytes` from the reused malloc heap (glibc only).

    Process-wide: sets M_MMAP_THRESHOLD and M_TRIM_THRESHOLD, so large per-frame buffers
    (the copies the Python custom ops make, numpy outputs) stop paying page faults on every
    call (measured at 720p: ORT-fast KernelApply overhead over the bare kernel ~75 -> ~35 ms)
    at the price of keeping freed memory mapped. Returns False where it does not apply.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    ok_mmap = mallopt(m_mmap_threshold, int(threshold_bytes)) == 1
    ok_trim = mallopt(m_trim_threshold, int(threshold_bytes)) == 1
    return ok_mmap and ok_trim
