"""Atomic file writes: a temp file beside the target, renamed over it only when complete.

A crash or an error mid-write leaves the previous file (or nothing), never a partial one; an
error or Ctrl-C removes the temp file. A killed process (SIGKILL, power loss) leaves it:
`temp_files_of` finds those of a target (`.<stem>.<random>.tmp<suffix>`), which `denoise-run`
removes before writing that target again.

Durable: the temp file's data is flushed to disk (fsync) before the rename, and the folder
after it (where the OS can: POSIX; Windows has no folder fsync), so that after a power loss
the target is either the old file or the complete new one, never a renamed empty file.
"""

from __future__ import annotations

import glob
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from ..errors import InputError
from ..interrupts import deferred_signals


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temp path to write to; on success it replaces `path`, on error it is removed."""
    path = Path(path)
    folder = path.parent
    if folder.exists() and not folder.is_dir():
        raise InputError(f"{folder}: output folder is a file")
    folder.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        # Ctrl-C held while the temp file is made: one that came between its creation and
        # `tmp` being set would leave it behind (seen once in 120-frame Ctrl-C runs)
        with deferred_signals():
            fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=_suffix(path), dir=folder)
            os.close(fd)
        yield Path(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual mode
        fsync_file(tmp)  # the data on disk before the name points at it
        os.replace(tmp, path)
        fsync_folder(folder)  # the rename itself on disk
    except BaseException:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise


def fsync_file(path: str | os.PathLike) -> None:
    """Flush a written file's data to the disk."""
    fd = os.open(path, os.O_RDONLY if os.name != "nt" else os.O_RDWR)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_folder(folder: str | os.PathLike) -> None:
    """Flush a folder's entries (a rename in it) to the disk where the OS allows it: POSIX;
    a no-op on Windows and on file systems that refuse to fsync a folder."""
    if os.name == "nt" or not hasattr(os, "O_DIRECTORY"):
        return
    try:
        fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # EINVAL: some file systems (e.g. some FUSE mounts) do not support it
        pass
    finally:
        os.close(fd)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def _prefix(path: Path) -> str:
    return f".{path.stem}."


def _suffix(path: Path) -> str:
    return f".tmp{path.suffix}"


def temp_files_of(path: str | os.PathLike) -> list[Path]:
    """Temp files `atomic_path` left beside `path` when its process was killed mid-write."""
    path = Path(path)
    prefix, suffix = _prefix(path), _suffix(path)
    if not path.parent.is_dir():
        return []
    return sorted(
        p
        for p in path.parent.glob(f"{glob.escape(prefix)}*{glob.escape(suffix)}")
        if len(p.name) == len(prefix) + 8 + len(suffix) and p.is_file()  # mkstemp: 8 chars
    )


def check_writable(path: str | os.PathLike) -> None:
    """InputError now, before any work, if a file cannot be written at `path` (a folder is in
    the way, no permission); its missing parent folders would be created."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file path")
    folder = path.parent
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{existing}: is a file, not a folder (writing {path})")
    if existing != folder:
        if not os.access(existing, os.W_OK | os.X_OK):
            raise InputError(f"{path}: cannot create folder {folder}: {existing} is not writable")
        return
    try:
        fd, probe = tempfile.mkstemp(prefix=_prefix(path), suffix=_suffix(path), dir=folder)
    except OSError as exc:
        raise InputError(f"{path}: cannot write in {folder} ({exc.strerror})") from exc
    os.close(fd)
    os.unlink(probe)


_UMASK: int | None = None


def _umask() -> int:
    """The process umask, read once (reading it means setting it: not thread-safe)."""
    global _UMASK
    if _UMASK is None:
        _UMASK = os.umask(0)
        os.umask(_UMASK)
    return _UMASK


_umask()
