"""Process-wide memory tuning for per-frame processing of large buffers: glibc's heap
(`tune_allocator`) and one CPU arena for every ONNX Runtime session (`share_cpu_arena`)."""

from __future__ import annotations

import ctypes
import sys
import threading

import onnxruntime as ort

# Session config key: allocate from the arena registered with ORT's environment.
USE_ENV_ALLOCATORS = "session.use_env_allocators"
_arena_lock = threading.Lock()
_arena_registered = False


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


def share_cpu_arena(options: ort.SessionOptions) -> bool:
    """Make the session allocate its CPU tensors from one arena shared by every session of the
    process that does the same (ONNX Runtime's environment allocator, registered here once per
    process; ONNX Runtime 1.31 replaces one registered before without a word, so this is for
    processes that register none of their own). Returns False, the options untouched, if ONNX
    Runtime refuses the registration.

    A session's own arena keeps the peak of its frames, so each session of a process holds
    its own (at 1080p: afn 2.1 GiB, affinity 5.5, crossreg 9.5). Shared, the intermediates one
    session frees at the end of its run serve the next session's run: models and sizes run in
    turn need the memory of the largest frame plus their states, not the sum, in the same or
    less time per frame (benchmarks/README.md, `shared_arena.py`).
    """
    global _arena_registered
    with _arena_lock:
        if not _arena_registered:
            cpu = ort.OrtMemoryInfo(
                "Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT
            )
            try:  # -1: ORT's defaults (no limit, chunks grown by powers of two)
                ort.create_and_register_allocator(cpu, ort.OrtArenaCfg(0, -1, -1, -1))
            except Exception:  # pybind errors derive from Exception only
                return False
            _arena_registered = True
    options.add_session_config_entry(USE_ENV_ALLOCATORS, "1")
    return True
