"""rtdenoise: deploy real-time Monte Carlo denoisers from PyTorch through ONNX Runtime.

The package's subpackages are the checkout's top-level folders, `rtdenoise.<name>` = `<name>/`
(`SUBPACKAGES`; docs/architecture.md, "Layers"). An install maps them (setup.py). In a checkout
the folder above this one also joins the package's search path, so that `import
rtdenoise.runtime` finds `runtime/` in an uninstalled checkout.

From a checkout's root, Python finds this folder first (the current folder leads `sys.path`
for `python -c`, `python -m` and the REPL), so it shadows a copy installed by `pip install .`.
Where such a copy is on `sys.path` (a folder `rtdenoise/` with its `runtime/`, not this one), the
package's search path is that copy alone: every submodule, `_version` included, comes from what
was installed (with the native bridge it compiled), as from any other folder. An editable
install has no such copy and keeps the checkout.
"""

import sys as _sys
from pathlib import Path as _Path

SUBPACKAGES = ("ops", "models", "export", "runtime", "cli", "datagen")


def _installed_copy(here: _Path) -> _Path | None:
    """The folder of a non-editable install of rtdenoise on sys.path other than `here`."""
    for entry in _sys.path:
        candidate = _Path(entry or ".") / "rtdenoise"
        try:
            if (candidate / "runtime" / "__init__.py").is_file() and (candidate.resolve() != here):
                return candidate.resolve()
        except OSError:  # an unreadable sys.path entry
            continue
    return None


_here = _Path(__file__).resolve().parent
_checkout = _here.parent
if (_checkout / "pyproject.toml").is_file() and all(
    (_checkout / name / "__init__.py").is_file() for name in SUBPACKAGES
):
    _installed = _installed_copy(_here)
    if _installed is not None:  # the checkout's root shadows an install: use the install
        __path__[:] = [str(_installed)]  # noqa: F821  (a package's own __path__)
    else:
        __path__.append(str(_checkout))  # noqa: F821

from ._version import __version__ as __version__  # noqa: E402  (after __path__ is final)
