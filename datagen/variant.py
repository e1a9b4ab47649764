"""Choose and set the Mitsuba 3 variant: `scalar_rgb` (works everywhere) or `llvm_ad_rgb`.

`llvm_ad_rgb` needs LLVM 19 (`apt-get install libllvm19`); with an older libLLVM
Dr.Jit aborts the whole process, so the variant is first probed in a subprocess
and we fall back to `scalar_rgb` with a clear message when it fails.
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
from collections.abc import Callable

SUPPORTED_VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
_LLVM_GLOBS = (
    "/usr/lib/llvm-19/lib/libLLVM.so*",
    "/usr/lib/*-linux-gnu/libLLVM.so.19*",
    "/usr/lib/*-linux-gnu/libLLVM-19.so*",
    "/usr/lib/libLLVM.so.19*",
    "/usr/lib/libLLVM-19.so*",
    "/usr/local/lib/libLLVM.so.19*",
)
_PROBE = (
    "import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); import drjit as dr; "
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


def probe_llvm(lib: str, timeout: float = 120.0) -> tuple[bool, str]:
    """Try `llvm_ad_rgb` in a subprocess (an incompatible LLVM aborts the process)."""
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=lib)
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        return False, "probe timed out"
    if r.returncode != 0:
        last = (r.stderr or r.stdout).strip().splitlines()
        return False, f"exit code {r.returncode}: {last[-1] if last else 'no output'}"
    return True, ""


def select_variant(requested: str, warn: Callable[[str], None] | None = None) -> str:
    """Set the Mitsuba variant (falling back to scalar_rgb when LLVM is unusable); return it."""
    if requested not in SUPPORTED_VARIANTS:
        raise ValueError(f"unknown variant {requested!r}; expected one of {SUPPORTED_VARIANTS}")
    warn = warn or (lambda msg: print(msg, file=sys.stderr))
    mi = require_mitsuba()
    variant = requested
    if requested == "llvm_ad_rgb":
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
