"""The EXR reader fuzz of tests/test_exr_fuzz.py, longer: `python benchmarks/fuzz_exr.py
[EXAMPLES] [--denoise]` (default 5000, random seed) prints the number of inputs tried and any
failure; --denoise also runs each frame that reads through demo:afn's `Denoiser.process`.
Run from the repository root (it imports tests/exr_fuzz.py)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from exr_fuzz import check_recipe, exr_files  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402


def main() -> None:
    args = [a for a in sys.argv[1:] if a != "--denoise"]
    examples = int(args[0]) if args else 5000
    denoiser = None
    if "--denoise" in sys.argv:
        from rtdenoise.runtime import Denoiser

        denoiser = Denoiser("demo:afn", threads=1)
    tried = 0

    @settings(
        max_examples=examples,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(exr_files())
    def fuzz(recipe):
        nonlocal tried
        tried += 1
        check_recipe(recipe, denoiser)

    start = time.perf_counter()
    fuzz()
    what = "EXR reader + Denoiser.process" if denoiser else "EXR reader"
    print(f"{what} fuzz: {tried} inputs tried, no failure, {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
