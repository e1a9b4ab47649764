"""The one place the version is written: pyproject.toml reads it (`[tool.setuptools.dynamic]`),
`rtdenoise.__version__` re-exports it and every CLI's `--version` prints it."""

__version__ = "0.1.0"
