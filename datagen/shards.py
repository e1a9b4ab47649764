"""Split a render job between processes: shards of indices and per-sequence lock files.

`--shard I/N` gives a process the indices i with i % N == I, so N processes started at once
on one folder never render the same sequence. A lock file (`seq_XXX/.lock`, created with
O_EXCL, holding host and pid) also keeps two processes with overlapping ranges apart: a
sequence another live process holds is skipped; the lock of a process that died on this host
is taken over (its sequence is resumed). A lock from another host is left alone (the
sequence is skipped), so remove it by hand if that host is gone.
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Iterable
from pathlib import Path

LOCK = ".lock"
STALE_EMPTY_S = 60.0  # an unreadable lock older than this is a leftover


def parse_shard(text: str) -> tuple[int, int]:
    """`I/N` -> (I, N) with 0 <= I < N; ValueError naming --shard otherwise."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must be I/N (e.g. 0/4), got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise ValueError(f"--shard I/N needs 0 <= I < N, got {text!r}")
    return i, n


def shard_indices(indices: Iterable[int], shard: tuple[int, int] | None) -> list[int]:
    """The indices of one shard (all of them without a shard)."""
    if shard is None:
        return list(indices)
    i, n = shard
    return [k for k in indices if k % n == i]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _owner(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0


def try_lock(seq_dir: Path) -> Path | None:
    """Take `seq_dir/.lock` (the folder is created); None when a live process holds it."""
    seq_dir.mkdir(parents=True, exist_ok=True)
    path = seq_dir / LOCK
    me = {"host": socket.gethostname(), "pid": os.getpid()}
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = _owner(path)
            if owner is None:  # being written right now (or left empty by a kill long ago)
                if time.time() - _mtime(path) < STALE_EMPTY_S:
                    return None
                path.unlink(missing_ok=True)
                continue
            if owner.get("host") != me["host"] or _alive(int(owner.get("pid", -1))):
                return None
            if _owner(path) == owner:  # stale: its process is gone; take it over
                path.unlink(missing_ok=True)
            continue
        with os.fdopen(fd, "w") as f:
            json.dump(me, f)
        return path
    return None


def release(lock: Path | None) -> None:
    """Remove a lock this process took."""
    if lock is not None and _owner(lock) == {"host": socket.gethostname(), "pid": os.getpid()}:
        lock.unlink(missing_ok=True)
