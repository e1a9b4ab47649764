"""`denoise-render`'s sequences as Ray tasks (docs/cluster.md): the same per-sequence code and
seeds as the local loop, so a data set is identical whichever way it was made.

Sequence i of a job is `render_index(out_dir, i, seed, cfg, variant)`: scene seed
`derive_seed(seed, i)`, written to `out_dir/seq_XXX/`, meta.json last (a folder without it
is incomplete and is rendered again, so a retried task simply starts over).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..runtime.sequences.cluster import DEFAULT_RETRIES, TaskContext, TaskOutcome, run_tasks
from .render import RenderConfig, derive_seed, render_sequence

_VARIANT_SET: dict[str, str] = {}  # requested -> used, once per worker process


def sequence_name(index: int) -> str:
    return f"seq_{index:03d}"


def render_index(
    out_dir: Path,
    index: int,
    seed: int,
    cfg: RenderConfig,
    variant: str,
    *,
    on_frame: Callable[[int], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
    references_from: Path | None = None,
) -> dict:
    """Render sequence `index` of the job with base seed `seed` (the variant already set);
    its RuntimeWarnings go to `on_warning`. Returns its meta.json content. `references_from`:
    a set rendered from the same seeds whose sequence `index` lends its references."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        meta = render_sequence(
            Path(out_dir) / sequence_name(index),
            derive_seed(seed, index),
            cfg,
            variant=variant,
            on_frame=on_frame,
            meta_extra={"job": {"base_seed": seed, "index": index}},
            references_from=None if references_from is None else (
                Path(references_from) / sequence_name(index)
            ),
        )  # fmt: skip
    for w in caught:
        if on_warning is not None:
            on_warning(str(w.message))
    return meta


def set_render_threads(threads: int | None) -> None:
    """Dr.Jit's worker threads (Mitsuba's render threads) in this process, when given."""
    if threads is None:
        return
    import drjit as dr

    if hasattr(dr, "set_thread_count"):
        dr.set_thread_count(threads)


def render_task(
    context: TaskContext,
    out_dir: Path,
    index: int,
    seed: int,
    cfg: RenderConfig,
    variant: str,
    threads: int | None,
    references_from: Path | None = None,
) -> str:
    """One sequence in a Ray worker: set the variant there (once per process), render it.
    Returns the variant used (a node without a usable LLVM falls back to scalar_rgb)."""
    from .variant import select_variant

    if variant not in _VARIANT_SET:
        _VARIANT_SET[variant] = select_variant(variant, warn=context.warn)
    else:
        import mitsuba as mi

        mi.set_variant(_VARIANT_SET[variant])
    set_render_threads(threads)
    context.start()
    render_index(
        out_dir,
        index,
        seed,
        cfg,
        _VARIANT_SET[variant],
        on_frame=lambda _t: context.frame(),
        on_warning=context.warn,
        references_from=references_from,
    )
    return _VARIANT_SET[variant]


def render_sequences(
    out_dir: Path,
    indices: Sequence[int],
    seed: int,
    cfg: RenderConfig,
    variant: str,
    *,
    threads: int | None = None,
    max_retries: int = DEFAULT_RETRIES,
    address: str | None = None,
    on_progress: Callable[[Mapping[str, int]], None] | None = None,
    on_done: Callable[[TaskOutcome], None] | None = None,
    references_from: Path | None = None,
) -> list[TaskOutcome]:
    """Render the sequences `indices` of a job as one Ray task each (`threads` CPUs each,
    default 1); outcomes named `seq_XXX`, in that order, the variant used as each result.
    `out_dir` must be on a file system every node shares."""
    args: list[tuple[str, tuple[Any, ...]]] = [
        (sequence_name(i), (Path(out_dir), i, seed, cfg, variant, threads, references_from))
        for i in indices
    ]
    return run_tasks(
        render_task,
        args,
        num_cpus=threads or 1,
        max_retries=max_retries,
        address=address,
        on_progress=on_progress,
        on_done=on_done,
    )


__all__ = [
    "render_index",
    "render_sequences",
    "render_task",
    "sequence_name",
    "set_render_threads",
]
