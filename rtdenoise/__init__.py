"""rtdenoise: deploy real-time Monte Carlo denoisers from PyTorch through ONNX Runtime.

The package's subpackages are the checkout's top-level folders, `rtdenoise.<name>` = `<name>/`
(`SUBPACKAGES`; docs/architecture.md, "Layers"). An install maps them (setup.py). In a checkout
the folder above this one also joins the package's search path, so that `import
rtdenoise.runtime` finds `runtime/` in an uninstalled checkout, and from the checkout's root
(where this folder shadows an installed copy) too.
"""

from pathlib import Path as _Path

from ._version import __version__ as __version__

SUBPACKAGES = ("ops", "models", "export", "runtime", "cli", "datagen")

_checkout = _Path(__file__).resolve().parent.parent
if (_checkout / "pyproject.toml").is_file() and all(
    (_checkout / name / "__init__.py").is_file() for name in SUBPACKAGES
):
    __path__.append(str(_checkout))  # noqa: F821  (a package's own __path__)
