"""Choose and set the Mitsuba 3 variant: `scalar_rgb` (works everywhere), `llvm_ad_rgb` (the
CPU's JIT) or `cuda_ad_rgb` (an NVIDIA GPU).

`llvm_ad_rgb` needs LLVM 19 (`apt-get install libllvm19`); with an older libLLVM
Dr.Jit aborts the whole process, so the variant is first probed in a subprocess
and we fall back to `scalar_rgb` with a clear message when it fails. `cuda_ad_rgb` needs
an NVIDIA driver (libcuda) and a mitsuba build that holds the variant (the PyPI wheels do);
it is probed the same way and falls back to `llvm_ad_rgb`, then `scalar_rgb`. The three render
the same scenes from the same seeds (samplers are seeded per frame), not bit for bit the same
pixels: each variant's floating-point order differs.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
from collections.abc import Callable

SUPPORTED_VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
_LLVM_GLOBS = (
    "/usr/lib/llvm-19/lib/libLLVM.so*",
    "/usr/lib/*-linux-gnu/libLLVM.so.19*",
    "/usr/lib/*-linux-gnu/libLLVM-19.so*",
    "/usr/lib/libLLVM.so.19*",
    "/usr/lib/libLLVM-19.so*",
    "/usr/local/lib/libLLVM.so.19*",
)
_PROBE = (
    "import mitsuba as mi; mi.set_variant({variant!r}); import drjit as dr; "
    "x = mi.Float([1.0, 2.0, 3.0]) * 2.0; dr.eval(x); print(x)"
)


def require_mitsuba():
    """Import mitsuba or raise ModuleNotFoundError (name 'mitsuba') with install advice."""
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise ModuleNotFoundError(
            "mitsuba is not installed: install the data extra: pip install 'rtdenoise[data]'",
            name="mitsuba",
        ) from exc
    return mi


def find_libllvm19() -> str | None:
    """Path of a libLLVM 19 shared library, from DRJIT_LIBLLVM_PATH or standard folders."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.isfile(env):
        return env
    for pattern in _LLVM_GLOBS:
        hits = sorted(glob.glob(pattern))
        if hits:
            return hits[0]
    return None


def probe_variant(
    variant: str, env: dict[str, str] | None = None, timeout: float = 120.0
) -> tuple[bool, str]:
    """Try a JIT variant in a subprocess (an unusable LLVM or CUDA aborts the process)."""
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE.format(variant=variant)],
            env=env if env is not None else dict(os.environ),
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return False, "probe timed out"
    if r.returncode != 0:
        last = (r.stderr or r.stdout).strip().splitlines()
        return False, f"exit code {r.returncode}: {last[-1] if last else 'no output'}"
    return True, ""


def probe_llvm(lib: str, timeout: float = 120.0) -> tuple[bool, str]:
    """Try `llvm_ad_rgb` with the libLLVM at `lib` in a subprocess."""
    return probe_variant("llvm_ad_rgb", dict(os.environ, DRJIT_LIBLLVM_PATH=lib), timeout)


def select_variant(requested: str, warn: Callable[[str], None] | None = None) -> str:
    """Set the Mitsuba variant, falling back cuda_ad_rgb -> llvm_ad_rgb -> scalar_rgb when a JIT
    backend is unusable (each fall named through `warn`); return the variant set."""
    if requested not in SUPPORTED_VARIANTS:
        raise ValueError(f"unknown variant {requested!r}; expected one of {SUPPORTED_VARIANTS}")
    warn = warn or (lambda msg: print(msg, file=sys.stderr))
    mi = require_mitsuba()
    variant = requested
    if requested == "cuda_ad_rgb":
        ok, why = probe_variant("cuda_ad_rgb")
        if not ok:
            warn(f"cuda_ad_rgb failed ({why}); falling back to llvm_ad_rgb")
            variant = "llvm_ad_rgb"
    if variant == "llvm_ad_rgb":
        lib = find_libllvm19()
        if lib is None:
            warn(
                "llvm_ad_rgb needs LLVM 19 (apt-get install libllvm19, or set "
                "DRJIT_LIBLLVM_PATH to libLLVM.so.19.x); falling back to scalar_rgb"
            )
            variant = "scalar_rgb"
        else:
            ok, why = probe_llvm(lib)
            if ok:
                os.environ["DRJIT_LIBLLVM_PATH"] = lib
            else:
                warn(f"llvm_ad_rgb failed with {lib} ({why}); falling back to scalar_rgb")
                variant = "scalar_rgb"
    mi.set_variant(variant)
    return variant
