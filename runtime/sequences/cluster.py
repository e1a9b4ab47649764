"""Many sequences at once on a Ray cluster: one sequence is one Ray task (docs/cluster.md).

Temporal state belongs to one sequence, so a batch of shots (or of sequences to render) is
embarrassingly parallel per sequence. `run_tasks` runs a per-sequence function as one Ray task
per sequence and collects one `TaskOutcome` each, in the order given; `run_shots` is
`denoise-run --cluster`: each task runs the very `run_sequence` of the local path.

- Progress: every task reports each frame to one small actor (`_Tracker`, no CPU of its
  own, kept on the driver's node); the driver polls it while it waits, so the caller hears
  per-frame progress.
- Failures: an exception inside a task (a bad file, a model error) is caught there and
  becomes that task's outcome (not retried: it would fail again); a lost worker or node is
  re-run by Ray up to `max_retries` times, then reported the same way. The other tasks finish.
- Reruns: each task applies `overwrite` / `resume` to its own outputs exactly as the local
  run does. A retry after a lost worker replaces the files the lost attempt wrote, never
  files that existed before the run.

Ray is imported only when a function here runs a batch (the `cluster` extra); torch never.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import InputError
from .backend import Backend, load_backend
from .layouts import Layout
from .run import Job, _targets, online_summary, run_sequence

DEFAULT_RETRIES = 3  # re-runs of a task whose worker or node was lost
POLL_S = 0.2  # how often the driver asks the tracker for progress

# Exceptions that mean bad input (exit 2 from the CLI, as `cli.common.user_errors` maps them).
INPUT_ERRORS: tuple[type[BaseException], ...] = (InputError, OSError, ValueError, KeyError)


@dataclass(frozen=True)
class BackendSpec:
    """How each task loads its own backend (`load_backend`'s arguments): a model spec, not a
    model, so that it travels to the workers. An .onnx path must be readable on every node."""

    model: str
    portable: bool = False
    threads: int | None = None
    providers: tuple[str, ...] = ()
    learn: bool = True
    learn_every: int = 1
    options: Mapping[str, float] | None = None  # run-time options, e.g. {"kernel_size": 7}
    relearn_at_cuts: bool = False

    def load(self) -> Backend:
        return load_backend(
            self.model,
            portable=self.portable,
            threads=self.threads,
            providers=self.providers,
            learn=self.learn,
            learn_every=self.learn_every,
            options=self.options,
            relearn_at_cuts=self.relearn_at_cuts,
        )


@dataclass
class TaskOutcome:
    """What became of one task: its result, or its error as one line."""

    name: str
    result: Any = None
    error: str | None = None  # "<ExceptionType>: <message>", None when it succeeded
    input_error: bool = False  # the error is bad input (InputError, OSError, ...)
    attempts: int = 0  # runs started (> 1 after a lost worker)
    seconds: float = 0.0  # wall time of the successful (or last) run in its worker
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.error is None


class _Tracker:
    """Ray actor: frames done and runs started per task (a retry starts again from 0)."""

    def __init__(self) -> None:
        self.frames: dict[str, int] = {}
        self.attempts: dict[str, int] = {}
        self.existed: dict[str, bool] = {}

    def start(self, name: str, existing: bool) -> tuple[int, bool]:
        """A run of `name` starts; -> (its attempt number, whether outputs existed at the first)."""
        self.attempts[name] = self.attempts.get(name, 0) + 1
        self.existed.setdefault(name, existing)
        self.frames[name] = 0
        return self.attempts[name], self.existed[name]

    def frame(self, name: str) -> None:
        self.frames[name] = self.frames.get(name, 0) + 1

    def snapshot(self) -> tuple[dict[str, int], dict[str, int]]:
        return dict(self.frames), dict(self.attempts)


class TaskContext:
    """What a task function gets as its first argument: report progress and warnings."""

    def __init__(self, name: str, tracker: Any) -> None:
        self.name = name
        self._tracker = tracker
        self.warnings: list[str] = []
        self.attempt = 0

    def start(self, existing: bool = False) -> tuple[int, bool]:
        """Call once when the task starts; `existing`: its outputs exist already. Returns
        (attempt number, whether outputs existed when the first attempt started)."""
        import ray

        self.attempt, existed = ray.get(self._tracker.start.remote(self.name, existing))
        return self.attempt, existed

    def frame(self) -> None:
        """One more frame done (fire and forget)."""
        self._tracker.frame.remote(self.name)

    def warn(self, message: str) -> None:
        self.warnings.append(message)


def _run_task(
    fn: Callable[..., Any], name: str, tracker: Any, cwd: str, args: tuple
) -> dict[str, Any]:
    """The Ray task: `fn(context, *args)` in the driver's working folder (so relative paths
    mean what they meant there), its exceptions caught and returned as one line."""
    ctx = TaskContext(name, tracker)
    t0 = time.perf_counter()
    if os.path.isdir(cwd):
        os.chdir(cwd)  # a worker runs one task at a time
    else:
        ctx.warn(f"{cwd}: the driver's folder is not on this node; relative paths may fail")
    out: dict[str, Any] = {"result": None, "error": None, "input_error": False}
    try:
        out["result"] = fn(ctx, *args)
    except Exception as exc:  # a task's own failure: reported by name, not retried
        text = " ".join(str(exc).split()) or "(no message)"
        out["error"] = f"{type(exc).__name__}: {text}"
        out["input_error"] = isinstance(exc, INPUT_ERRORS)
    out.update(attempt=max(ctx.attempt, 1), seconds=time.perf_counter() - t0, warnings=ctx.warnings)
    return out


def connect(address: str | None = None, *, num_cpus: int | None = None) -> bool:
    """Make sure this process is connected to Ray; True when this call connected it (the
    caller then calls `ray.shutdown()`), False when it already was.

    address: a cluster to join (`ray://host:10001`, `host:6379`, or `auto`: the one started
    on this machine with `ray start --head`); None: $RAY_ADDRESS when set, else a new local
    instance (never a stale cluster Ray remembers). num_cpus: CPUs of a new local instance
    (default: all).
    """
    try:
        import ray
    except ImportError as exc:
        raise ModuleNotFoundError(
            "ray is not installed: install the cluster extra: pip install 'rtdenoise[cluster]'",
            name="ray",
        ) from exc
    if ray.is_initialized():
        return False
    kwargs: dict[str, Any] = {"logging_level": logging.WARNING, "log_to_driver": False}
    if address is None:
        address = os.environ.get("RAY_ADDRESS") or "local"
    if address == "local" and num_cpus is not None:
        kwargs["num_cpus"] = num_cpus
    ray.init(address=address, **kwargs)
    return True


def run_tasks(
    fn: Callable[..., Any],
    tasks: Sequence[tuple[str, tuple]],
    *,
    num_cpus: float = 1,
    num_gpus: float = 0,
    max_retries: int = DEFAULT_RETRIES,
    address: str | None = None,
    on_progress: Callable[[Mapping[str, int]], None] | None = None,
    on_done: Callable[[TaskOutcome], None] | None = None,
) -> list[TaskOutcome]:
    """Run `fn(context, *args)` as one Ray task per (name, args); outcomes in that order.

    fn: a module-level function (the workers import it by name), first argument a
        `TaskContext`: it calls `context.start()` once, `context.frame()` per frame.
    num_cpus, num_gpus: what Ray reserves for each task (`num_gpus` > 0: Ray sets
        CUDA_VISIBLE_DEVICES for it). max_retries: re-runs after a lost worker or node.
    on_progress: frames done so far per task name, every `POLL_S` seconds while waiting.
    on_done: each outcome as soon as its task ends (completion order).
    Connects to Ray first (`connect(address)`) and disconnects after if it connected.
    """
    names = [name for name, _ in tasks]
    if len(set(names)) != len(names):
        raise InputError("two tasks share a name; every sequence needs its own")
    started = connect(address)
    import ray
    from ray.exceptions import RayError

    pending: dict[Any, str] = {}
    try:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=True)
        tracker = ray.remote(num_cpus=0, scheduling_strategy=here)(_Tracker).remote()
        remote = ray.remote(_run_task)
        cwd = os.getcwd()
        resources = {"num_cpus": num_cpus, "num_gpus": num_gpus, "max_retries": max_retries}
        for name, args in tasks:
            task = remote.options(name=f"rtdenoise {name}", retry_exceptions=False, **resources)
            pending[task.remote(fn, name, tracker, cwd, args)] = name
        outcomes: dict[str, TaskOutcome] = {}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1, timeout=POLL_S)
            frames, attempts = ray.get(tracker.snapshot.remote())
            if on_progress is not None:
                on_progress(frames)
            for ref in done:
                name = pending.pop(ref)
                try:
                    out = ray.get(ref)
                    outcome = TaskOutcome(
                        name,
                        out["result"],
                        out["error"],
                        out["input_error"],
                        out["attempt"],
                        out["seconds"],
                        out["warnings"],
                    )
                except RayError as exc:  # the worker or node was lost, retries used up
                    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
                    tries = attempts.get(name, max_retries + 1)
                    outcome = TaskOutcome(
                        name, error=f"{type(exc).__name__}: {first}", attempts=tries
                    )
                outcomes[name] = outcome
                if on_done is not None:
                    on_done(outcome)
        return [outcomes[name] for name in names]
    except BaseException:  # Ctrl-C or a driver error: stop what still runs
        for ref in pending:
            ray.cancel(ref)
        raise
    finally:
        if started:
            ray.shutdown()


def _set_threads(threads: int | None) -> None:
    """Cap numba's threads in this worker at the task's share (ONNX Runtime's are set by the
    Denoiser); nothing when numba is absent or `threads` is None."""
    if threads is None:
        return
    try:
        import numba
    except ImportError:
        return
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))


def denoise_shot(
    context: TaskContext,
    job: Job,
    backend: BackendSpec | Callable[[], Backend],
    layout: Layout | str,
    overrides: dict[str, str],
    options: dict[str, Any],
) -> dict[str, Any]:
    """One shot in a worker: the local path's `run_sequence`, plus `online` as `denoise-run`
    reports it. options: run_sequence's keywords (half, preview, overwrite, resume, max_pixels)."""
    options = dict(options)
    if isinstance(backend, BackendSpec):
        _set_threads(backend.threads)
    preview = bool(options.get("preview", False))
    existing = any(
        t.exists() for p in job.frames for t in _targets(Path(job.out_dir) / p.name, preview)
    )
    attempt, existed = context.start(existing)
    if attempt > 1 and not existed and not (options.get("overwrite") or options.get("resume")):
        options["overwrite"] = True  # the files are the lost attempt's own, not an earlier run's
    loaded = backend.load() if isinstance(backend, BackendSpec) else backend()
    report = run_sequence(
        job, loaded, layout, overrides, on_frame=context.frame, on_warning=context.warn, **options
    )
    report["online"] = online_summary(loaded)
    return report


def run_shots(
    jobs: Sequence[Job],
    backend: BackendSpec | Callable[[], Backend],
    layout: Layout | str = "canonical",
    overrides: dict[str, str] | None = None,
    *,
    half: bool = True,
    preview: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    max_pixels: int | None = None,
    num_cpus: float | None = None,
    num_gpus: float = 0,
    max_retries: int = DEFAULT_RETRIES,
    address: str | None = None,
    on_progress: Callable[[Mapping[str, int]], None] | None = None,
    on_done: Callable[[TaskOutcome], None] | None = None,
) -> list[TaskOutcome]:
    """Denoise each job (one sequence) as one Ray task; outcomes in the jobs' order, each
    with the sequence's report (`run_sequence`'s, plus `online`) as its result.

    backend: a `BackendSpec` (each task loads its model; its `threads` are also the task's
        `num_cpus` unless given) or a module-level factory returning a `Backend`.
    Every path (frames, model, layout file, outputs) must mean the same file on every node:
    a shared file system (docs/cluster.md). Other arguments as `run_tasks` and `run_sequence`.
    """
    if overwrite and resume:
        raise InputError("--overwrite and --resume exclude each other")
    if num_cpus is None:
        threads = backend.threads if isinstance(backend, BackendSpec) else None
        num_cpus = threads or 1
    options = {
        "half": half,
        "preview": preview,
        "overwrite": overwrite,
        "resume": resume,
        "max_pixels": max_pixels,
    }
    return run_tasks(
        denoise_shot,
        [(job.name, (job, backend, layout, dict(overrides or {}), options)) for job in jobs],
        num_cpus=num_cpus,
        num_gpus=num_gpus,
        max_retries=max_retries,
        address=address,
        on_progress=on_progress,
        on_done=on_done,
    )


__all__ = [
    "DEFAULT_RETRIES",
    "BackendSpec",
    "TaskContext",
    "TaskOutcome",
    "connect",
    "denoise_shot",
    "run_shots",
    "run_tasks",
]
