"""Property-based fuzz of the EXR reader and, with what it reads, of `Denoiser.process`
(issue 27, item 9): bounded to some 60 s here; benchmarks/fuzz_exr.py runs it longer."""

from __future__ import annotations

import pytest
from exr_fuzz import check_recipe, exr_files
from hypothesis import HealthCheck, given, settings

from rtdenoise.runtime import Denoiser


@pytest.fixture(scope="module")
def denoiser():
    return Denoiser("demo:afn", threads=1)


@settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(exr_files())
def test_exr_reader_never_raises_anything_but_one_input_error(recipe):
    check_recipe(recipe)


def test_what_the_reader_gives_denoises_to_a_finite_image(denoiser):
    @settings(
        max_examples=60,
        deadline=None,
        derandomize=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(exr_files())
    def check(recipe):
        check_recipe(recipe, denoiser)

    check()
