"""Helpers shared by the CLI apps: one-line errors, warnings, JSON output."""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import typer

from rtdenoise.runtime.atomic import write_text_atomic
from rtdenoise.runtime.errors import InputError

EXIT_BAD_INPUT = 2
EXIT_FAILURE = 1


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
def user_errors() -> Iterator[None]:
    """Turn bad-input exceptions into one-line errors: exit 2 for input problems
    (InputError, OSError, ValueError), exit 1 for a processing failure (RuntimeError)."""
    try:
        yield
    except typer.Exit:
        raise
    except (InputError, OSError, ValueError, KeyError) as exc:
        fail(exc, EXIT_BAD_INPUT)
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


def passive_openmp_threads() -> None:
    """Let idle OpenMP workers sleep instead of spin (unless the user chose otherwise).

    On a shared 2-core machine spinning workers made a 2-thread training step 40x slower
    (21 s vs 0.5 s, measured). libgomp reads it when torch loads: call before `import torch`.
    """
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
