"""runtime/kernels/cache.py: numba's cached kernels are cleared when any kernel source changes
(numba itself only notices a change in the file of the function it compiled)."""

from __future__ import annotations

import os
from pathlib import Path

from rtdenoise.runtime.kernels import cache


def _cached(folder: Path, name: str) -> Path:
    path = folder / "__pycache__" / name
    path.write_bytes(b"compiled")
    return path


def test_cache_cleared_when_a_source_changes_and_kept_otherwise(tmp_path: Path) -> None:
    (tmp_path / "helper.py").write_text("def row(): return 1\n")
    (tmp_path / "caller.py").write_text("from .helper import row\n")
    (tmp_path / "__pycache__").mkdir()
    stale = _cached(tmp_path, "caller.row-3.py311.nbi")
    assert cache.clear_if_sources_changed(tmp_path)  # no stamp yet: cleared, stamped
    assert not stale.exists() and (tmp_path / "__pycache__" / cache.STAMP).exists()

    fresh = [_cached(tmp_path, n) for n in ("caller.row-3.py311.nbi", "caller.row-3.py311.0.nbc")]
    assert not cache.clear_if_sources_changed(tmp_path)  # same sources: kept
    assert all(p.exists() for p in fresh)

    (tmp_path / "helper.py").write_text("def row(): return 2\n")  # only the inlined helper
    assert cache.clear_if_sources_changed(tmp_path)
    assert not any(p.exists() for p in fresh)
    assert (tmp_path / "caller.py").exists() and (tmp_path / "helper.py").exists()


def test_unwritable_or_missing_cache_is_not_an_error(tmp_path: Path) -> None:
    (tmp_path / "k.py").write_text("x = 1\n")
    (tmp_path / "__pycache__").write_text("not a directory")  # mkdir and writes fail
    assert cache.clear_if_sources_changed(tmp_path) is False


def test_installed_kernels_are_stamped() -> None:
    """Importing the kernels stamped their cache (unless the install is read-only, where numba
    caches elsewhere)."""
    folder = Path(cache.__file__).parent
    if os.access(folder, os.W_OK):
        stamp = folder / "__pycache__" / cache.STAMP
        assert stamp.read_text() == cache.sources_hash(cache.kernel_sources())
