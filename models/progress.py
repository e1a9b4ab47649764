"""Progress of a training run, with its ETA: a rich bar on a terminal, plain lines elsewhere.

As cli/common.py `progress_status` does for the other commands: rich draws nothing useful into a
log file or a pipe, so there (and with the bar turned off) each logging window prints one line,
`step 1200/20000: loss 0.0734, lr 9.1e-04, 0.41 s/step, elapsed 8:12, ETA 2:08:40`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def clock(seconds: float) -> str:
    """`h:mm:ss` (or `m:ss` under an hour) of a duration in seconds."""
    s = max(0, int(round(seconds)))
    h, m, s = s // 3600, s // 60 % 60, s % 60
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class TrainProgress:
    """`bar=True` (a terminal): rich progress bar (on stderr unless `console` says otherwise)
    with loss, lr, elapsed and remaining time; otherwise `window` logs a line per logging
    window through `log`."""

    def __init__(
        self,
        total: int,
        start: int,
        *,
        bar: bool,
        log: Callable[[str], None] = print,
        console: Any = None,
    ) -> None:
        self.total, self.start, self.log = int(total), int(start), log
        self.t0 = time.perf_counter()
        self.bar = None
        if bar:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self.bar = Progress(
                TextColumn("[bold]train"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("loss {task.fields[loss]} lr {task.fields[lr]}"),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                console=console if console is not None else Console(stderr=True),
            )
            self.task = self.bar.add_task("train", total=total, completed=start, loss="-", lr="-")

    def __enter__(self) -> TrainProgress:
        if self.bar is not None:
            self.bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()

    def eta(self, step: int) -> tuple[float, float, float]:
        """(elapsed s, s per step, remaining s) of this process at `step`."""
        elapsed = time.perf_counter() - self.t0
        per_step = elapsed / max(1, step - self.start)
        return elapsed, per_step, per_step * max(0, self.total - step)

    def update(self, step: int, loss: float, lr: float) -> None:
        """After each step: advance the bar."""
        if self.bar is not None:
            self.bar.update(self.task, completed=step, loss=f"{loss:.4f}", lr=f"{lr:.1e}")

    def window(self, step: int, mean_loss: float, lr: float) -> None:
        """After each logging window: a plain line, unless the bar shows it all."""
        if self.bar is not None:
            return
        elapsed, per_step, left = self.eta(step)
        self.log(
            f"step {step}/{self.total}: loss {mean_loss:.4f}, lr {lr:.1e}, {per_step:.3f} s/step, "
            f"elapsed {clock(elapsed)}, ETA {clock(left)}"
        )


__all__ = ["TrainProgress", "clock"]
