"""Keep numba's on-disk cache of the kernels in step with their sources.

numba keys a cached function on the file it is defined in (path, modification time, size),
not on the files of the functions it inlines: `softmax_kernel_apply` compiled against
`kernel_apply.apply_row` keeps that old code after `kernel_apply.py` changes (as in a
checkout that pulls a change). `clear_if_sources_changed` stamps the cache directory with a
hash of every kernel source and clears the cached code when the hash differs. A fresh install
writes new files and has no cache yet, so there it only writes the stamp.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

STAMP = "rtdenoise-kernels.sha256"


def sources_hash(sources: Iterable[Path]) -> str:
    digest = hashlib.sha256()
    for path in sorted(sources):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def kernel_sources() -> list[Path]:
    """The kernels' source files (what any numba-compiled caller may inline)."""
    return sorted(Path(__file__).parent.glob("*.py"))


def clear_if_sources_changed(folder: Path, sources: Iterable[Path] | None = None) -> bool:
    """Clear numba's cache files in `folder`/__pycache__ if `sources` (default: the .py files
    of `folder`) changed since the stamp there was written; returns whether it cleared. Never
    raises on a read-only or missing cache directory (numba then caches elsewhere or not at
    all)."""
    cache = folder / "__pycache__"
    current = sources_hash(sorted(folder.glob("*.py")) if sources is None else sources)
    try:
        if (cache / STAMP).read_text() == current:
            return False
    except OSError:
        pass
    cleared = False
    try:
        for path in cache.glob("*.nb[ic]"):
            path.unlink(missing_ok=True)
            cleared = True
        cache.mkdir(exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=cache, prefix=STAMP)
        with os.fdopen(fd, "w") as f:
            f.write(current)
        os.replace(tmp, cache / STAMP)
    except OSError:
        pass
    return cleared
