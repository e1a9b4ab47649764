"""Helpers shared by the CLI apps: one-line errors, warnings, JSON output, `--version`,
the extra a command needs."""

from __future__ import annotations

import json
import math
import os
import platform
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from rtdenoise import __version__
from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.atomic import write_text_atomic

# Every command's Typer app: `-h` as well as `--help` (subcommands inherit it).
CONTEXT_SETTINGS: dict[str, Any] = {"help_option_names": ["-h", "--help"]}

EXIT_BAD_INPUT = 2
EXIT_FAILURE = 1

# Modules that only an extra installs (pyproject.toml, [project.optional-dependencies]).
# Modules only an extra installs (numba, onnxruntime_extensions: the `numba` extra, which
# `export` and `train` include).
OPTIONAL_MODULES = frozenset(
    {"torch", "onnx", "onnxscript", "mitsuba", "drjit", "pyoidn", "ray", "numba",
     "onnxruntime_extensions"}
)  # fmt: skip
# Distributions whose versions `--version` reports (metadata only: nothing is imported).
REPORTED_VERSIONS = ("onnxruntime", "onnxruntime-extensions", "numba", "numpy", "torch")


def version_line() -> str:
    """`rtdenoise X (Python Y; onnxruntime Z, ...)`: what a bug report needs, torch included
    when installed, read from package metadata without importing anything."""
    parts = []
    for dist in REPORTED_VERSIONS:
        try:
            parts.append(f"{dist} {metadata.version(dist)}")
        except metadata.PackageNotFoundError:
            parts.append(f"{dist} absent")
    return f"rtdenoise {__version__} (Python {platform.python_version()}; {', '.join(parts)})"


def _show_version(value: bool) -> None:
    if value:
        print(version_line())
        raise typer.Exit()


VersionOption = Annotated[
    bool,
    typer.Option(
        "--version", callback=_show_version, is_eager=True, help="Show the version and exit."
    ),
]


FamilyModuleOption = Annotated[
    list[str] | None,
    typer.Option(
        "--family-module",
        metavar="MODULE",
        help="Import MODULE (a dotted name found from this folder too, or a .py file) first, "
        "for a denoiser family defined outside rtdenoise and not installed as a package; "
        "repeatable (installed packages join through the 'rtdenoise.families' entry points).",
    ),
]


def load_family_modules(modules: list[str] | None) -> None:
    """Import every `--family-module` (models.registry.load_family_module); needs torch."""
    from rtdenoise.models.registry import load_family_module

    for module in modules or []:
        load_family_module(module)


def family_names() -> list[str]:
    """The families the installed entry points declare, found without importing them (so
    without torch): `--help` lists them even where the train extra is missing."""
    from rtdenoise.ops.plugins import FAMILIES, entry_points

    return sorted({ep.name for ep in entry_points(FAMILIES)})


def one_line(exc: BaseException | str) -> str:
    """The message of an exception (or text) squeezed onto one line."""
    text = str(exc).strip() or type(exc).__name__
    return " ".join(part.strip() for part in text.splitlines() if part.strip())


def fail(message: BaseException | str, code: int = EXIT_BAD_INPUT) -> NoReturn:
    """Print `error: <message>` as one plain line on stderr and exit with `code`."""
    print(f"error: {one_line(message)}", file=sys.stderr, flush=True)
    raise typer.Exit(code)


def warn(message: str) -> None:
    """Print `warning: <message>` as one plain line on stderr."""
    print(f"warning: {one_line(message)}", file=sys.stderr, flush=True)


@contextmanager
def progress_status(console: Any, label: str) -> Iterator[Any]:
    """`with progress_status(console, "comparing") as say: say("720p")`: rich's status line on
    a terminal; elsewhere (a log, a pipe), where rich shows nothing, each message as a plain
    line on stderr (`comparing: 720p`), so a long run is not silent."""
    if console.is_terminal:
        with console.status(label) as status:
            yield lambda message: status.update(f"{label}: {message}")
    else:
        yield lambda message: print(f"{label}: {message}", file=sys.stderr, flush=True)


def missing_extra_message(exc: ModuleNotFoundError, extra: str) -> str | None:
    """`no module named 'torch': install the export extra: ...` when `exc` is a module that
    only an extra installs; None for any other missing module (a broken install)."""
    root = (exc.name or "").split(".")[0]
    if root not in OPTIONAL_MODULES:
        return None
    return (
        f"no module named {root!r}: this command needs the {extra} extra: "
        f"pip install 'rtdenoise[{extra}]'"
    )


@contextmanager
def user_errors(extra: str | None = None) -> Iterator[None]:
    """Turn bad-input exceptions into one-line errors: exit 2 for input problems
    (InputError, OSError, ValueError), exit 1 for a processing failure (RuntimeError).

    extra: the extra the command needs (pyproject.toml); a missing module of an extra
    becomes `error: ... pip install 'rtdenoise[<extra>]'` (exit 2).
    """
    try:
        yield
    except typer.Exit:
        raise
    except ModuleNotFoundError as exc:
        message = missing_extra_message(exc, extra) if extra else None
        if message is None:
            raise
        fail(message, EXIT_BAD_INPUT)
    except (InputError, OSError, ValueError, KeyError) as exc:
        fail(exc, EXIT_BAD_INPUT)
    except MemoryError as exc:  # where no caller named the file and size first
        fail(f"out of memory ({exc or 'MemoryError'}): free memory or lower --max-pixels")
    except RuntimeError as exc:
        fail(exc, EXIT_FAILURE)


@contextmanager
def quiet_native_output() -> Iterator[None]:
    """Silence what native libraries print on file descriptors 1 and 2 meanwhile.

    OpenEXR prints its own diagnostics for a corrupt file (C stderr, C++ stdout) before the
    Python binding raises; the CLI reports the problem itself, as one line. Process-wide:
    wrap only the reading calls, never the CLI's own output.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def parse_size(text: str, option: str = "--size") -> tuple[int, int]:
    """`WIDTHxHEIGHT` (e.g. 1280x720) -> (width, height); InputError otherwise."""
    w, sep, h = text.strip().lower().partition("x")
    if not (sep and w.strip().isdigit() and h.strip().isdigit() and int(w) > 0 and int(h) > 0):
        raise InputError(f"{option} {text!r}: expected WIDTHxHEIGHT, e.g. 1280x720")
    return int(w), int(h)


def json_safe(obj: Any) -> Any:
    """Replace non-finite floats (inf PSNR of identical images, NaN) by None; numpy -> Python."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "item") and not isinstance(obj, str | bytes):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write strict JSON (no NaN/Infinity) atomically: temp file in the folder, then rename."""
    path = Path(path)
    text = json.dumps(json_safe(obj), indent=2, allow_nan=False) + "\n"
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a JSON file path")
    if path.parent.exists() and not path.parent.is_dir():
        raise InputError(f"{path.parent}: is a file, not a folder")
    write_text_atomic(path, text)
    return path


def one_line_warnings() -> None:
    """Show Python warnings (e.g. the fast kernels' fallback) as `warning: <message>` lines on
    stderr, like the CLI's own, instead of file:line plus source. Process-wide: mains only."""
    warnings.showwarning = lambda message, *_args, **_kw: warn(str(message))


def passive_openmp_threads() -> None:
    """Let idle OpenMP workers sleep instead of spin (unless the user chose otherwise).

    On a shared 2-core machine spinning workers made a 2-thread training step 40x slower
    (21 s vs 0.5 s, measured). libgomp reads it when torch loads: call before `import torch`.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _hide_flag_types() -> None:
    """Show no `<bool>` after plain flags (`--preview`, `--help`) in rich help, as click's
    plain help does: typer >= 0.20 (vendored click) prints their type there. Process-wide,
    idempotent; a typer without `TyperOption.display_type_rich` is left alone."""
    try:
        from typer.core import TyperOption
    except ImportError:  # pragma: no cover - other typer layouts
        return
    original = getattr(TyperOption, "display_type_rich", None)
    if original is None or getattr(original, "hides_flag_types", False):
        return

    def display_type_rich(self: Any, ctx: Any) -> str | None:
        if getattr(self, "is_flag", False) and self.metavar is None:
            return None
        return original(self, ctx)

    display_type_rich.hides_flag_types = True  # type: ignore[attr-defined]
    TyperOption.display_type_rich = display_type_rich


_hide_flag_types()
