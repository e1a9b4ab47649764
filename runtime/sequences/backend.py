"""The denoising backend `denoise-run` drives: anything with `process` and `reset`.

`PassThrough` (``--model none``) returns the noisy colour unchanged: a diagnostic of
the I/O path, progress, metrics and previews. Every other model spec (an .onnx path
or ``demo:<family>``) loads `rtdenoise.runtime.Denoiser`, imported lazily.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import InputError


@runtime_checkable
class Backend(Protocol):
    """One stateful denoiser: frames in order, `reset()` at a cut.

    A backend may also list `required_buffers` (names): `run_sequence` then reads only
    those (and `color`); without it, every buffer the layout finds. One with `last_guard`
    (a `runtime.guard.GuardReport`, as `Denoiser` has) gets what it reports warned per frame.
    """

    def process(self, buffers: Mapping[str, np.ndarray]) -> np.ndarray:
        """Denoise one frame: canonical (C, H, W) buffers -> (3, H, W) linear RGB."""
        ...

    def reset(self) -> None:
        """Forget the history; the next frame starts a new sequence."""
        ...


class PassThrough:
    """``--model none``: the output is the input `color`, copied."""

    name = "none"
    required_buffers: tuple[str, ...] = ("color",)

    def process(self, buffers: Mapping[str, np.ndarray]) -> np.ndarray:
        """A copy of `color`, NaN/Inf included (there is no model to protect)."""
        if "color" not in buffers:
            raise InputError("pass-through needs the 'color' buffer")
        return np.array(buffers["color"], dtype=np.float32, copy=True)

    def reset(self) -> None:
        pass


def load_backend(
    model: str,
    *,
    portable: bool = False,
    threads: int | None = None,
    providers: Sequence[str] | None = None,
    learn: bool = True,
    learn_every: int = 1,
    options: Mapping[str, float] | None = None,
    relearn_at_cuts: bool = False,
) -> Backend:
    """`none` -> PassThrough; an .onnx path or `demo:<family>` -> Denoiser.

    portable: run the custom ops' standard-ONNX function bodies instead of the fast kernels.
    providers: ONNX Runtime execution providers in order of preference (None or empty: CPU).
    learn, learn_every, relearn_at_cuts: online learning of a model that learns while it runs
        (Denoiser).
    options: values of the model's run-time options (e.g. {"kernel_size": 7}).
    """
    if model.strip().lower() == "none":
        if options:
            raise InputError(f"--model none has no run-time options ({', '.join(options)})")
        return PassThrough()
    try:
        from ..denoiser import Denoiser
    except ImportError as exc:
        raise InputError(f"the ONNX backend is not available ({exc}); use --model none") from exc
    return Denoiser(
        model,
        fast_kernels=not portable,
        threads=threads,
        providers=list(providers or []) or None,
        learn=learn,
        learn_every=learn_every,
        relearn_at_cuts=relearn_at_cuts,
        overrides=options,
    )
