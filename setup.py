"""Map the top-level folders onto the one import package `rtdenoise` (docs/architecture.md).

`rtdenoise.<name>` is the folder `<name>/`; every sub-package of a mapped folder is found, so
adding a package needs no edit here. All other metadata lives in pyproject.toml.
"""

from setuptools import find_packages, setup

ROOTS = {
    "rtdenoise": "rtdenoise",
    "rtdenoise.ops": "ops",
    "rtdenoise.models": "models",
    "rtdenoise.export": "export",
    "rtdenoise.runtime": "runtime",
    "rtdenoise.cli": "cli",
    "rtdenoise.datagen": "datagen",
}

setup(
    package_dir=ROOTS,
    packages=[
        f"{package}.{sub}" if sub else package
        for package, folder in ROOTS.items()
        for sub in ["", *find_packages(folder)]
    ],
)
