"""What `denoise-run --cluster` and `denoise-render --cluster` share: the options, one progress
bar over every frame of every task, the failure lines and the exit code (docs/cluster.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from rtdenoise.cli.common import EXIT_BAD_INPUT, EXIT_FAILURE
from rtdenoise.cli.progress import plain_line
from rtdenoise.runtime.sequences.cluster import DEFAULT_RETRIES, TaskOutcome

ClusterOption = Annotated[
    bool,
    typer.Option(
        "--cluster",
        help="Run each sequence as one Ray task (the `cluster` extra; docs/cluster.md): on the "
        "cluster at --cluster-address, else at $RAY_ADDRESS, else on a new local Ray on all "
        "cores. Paths must be on a file system every node shares.",
    ),
]
ClusterAddressOption = Annotated[
    str | None,
    typer.Option(
        "--cluster-address",
        metavar="ADDRESS",
        help="Join this Ray cluster (implies --cluster): `auto` (the one started on this "
        "machine), `HEAD:6379`, or `ray://HEAD:10001` (Ray Client).",
        show_default=False,
    ),
]
RetriesOption = Annotated[
    int,
    typer.Option(
        "--retries",
        min=0,
        help="With --cluster: re-run a sequence whose worker or node was lost up to N times "
        "(errors of the sequence itself, e.g. a bad file, are not retried).",
    ),
]


@contextmanager
def task_progress(
    err: Console, totals: Mapping[str, int], what: str
) -> Iterator[tuple[Callable[[Mapping[str, int]], None], Callable[[TaskOutcome], None]]]:
    """One bar over the frames of all tasks: yields `run_tasks`' (on_progress, on_done).
    Where stderr is no terminal (rich shows nothing), a plain line as each task ends:
    `denoise: seq_000 done (1/3)`, `denoise: seq_001 failed (2/3)`."""
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )
    frames = dict.fromkeys(totals, 0)
    ended: dict[str, bool] = {}

    def describe() -> str:
        failed = sum(not ok for ok in ended.values())
        text = f"{what}: {len(ended)}/{len(totals)} done"
        return text + (f", {failed} failed" if failed else "")

    with progress:
        bar = progress.add_task(describe(), total=sum(totals.values()))

        def on_progress(done: Mapping[str, int]) -> None:
            for name, n in done.items():
                if name in frames and name not in ended:
                    frames[name] = min(n, totals[name])
            progress.update(bar, completed=sum(frames.values()), description=describe())

        def on_done(outcome: TaskOutcome) -> None:
            ended[outcome.name] = outcome.ok
            frames[outcome.name] = totals[outcome.name]  # a failed one counts as finished
            progress.update(bar, completed=sum(frames.values()), description=describe())
            if not err.is_terminal:
                state = "done" if outcome.ok else "failed"
                plain_line(f"{what}: {outcome.name} {state} ({len(ended)}/{len(totals)})")

        yield on_progress, on_done


def report_failures(outcomes: Sequence[TaskOutcome], what: str) -> int:
    """`error: <what> <name>: <error>` per failed task on stderr; the exit code: 0 when all
    succeeded, 2 when every failure was bad input, else 1."""
    failed = [o for o in outcomes if not o.ok]
    for o in failed:
        tries = f" (after {o.attempts} attempts)" if o.attempts > 1 else ""
        typer.echo(f"error: {what} {o.name}{tries}: {o.error}", err=True)
    if not failed:
        return 0
    return EXIT_BAD_INPUT if all(o.input_error for o in failed) else EXIT_FAILURE


__all__ = [
    "DEFAULT_RETRIES",
    "ClusterAddressOption",
    "ClusterOption",
    "RetriesOption",
    "report_failures",
    "task_progress",
]
