"""Map the top-level folders onto the one import package `rtdenoise` (docs/architecture.md).

`rtdenoise.<name>` is the folder `<name>/` for every name of `rtdenoise.SUBPACKAGES` (which a
checkout uses the same way: rtdenoise/__init__.py); every sub-package of a mapped folder is
found, so adding a package needs no edit here. All other metadata lives in pyproject.toml.

The one compiled part is the native custom-op bridge (runtime/bridge/_ort_bridge.c, a plain C
file against ONNX Runtime's C ABI): optional, so that an install without a C compiler still
works and runs the fast kernels through onnxruntime-extensions instead
(runtime/bridge/native.py).

A release wheel must carry every native part: with RTDENOISE_REQUIRE_EXTENSIONS=1 (set by
[tool.cibuildwheel] and scripts/build_release_wheel.sh) no extension is optional, so a compile
failure fails the build instead of shipping a wheel without it.
"""

import os

from setuptools import Extension, find_packages, setup

SUBPACKAGES = ("ops", "models", "export", "runtime", "cli", "datagen")  # = rtdenoise.SUBPACKAGES
ROOTS = {"rtdenoise": "rtdenoise"} | {f"rtdenoise.{name}": name for name in SUBPACKAGES}

BRIDGE = Extension(
    "rtdenoise.runtime.bridge._ort_bridge",
    sources=["runtime/bridge/_ort_bridge.c"],
    optional=True,
)



def release_extensions(extensions: list[Extension]) -> list[Extension]:
    """`extensions`, none optional when RTDENOISE_REQUIRE_EXTENSIONS=1 (a release build)."""
    if os.environ.get("RTDENOISE_REQUIRE_EXTENSIONS") == "1":
        for ext in extensions:
            ext.optional = False
    return extensions


setup(
    ext_modules=release_extensions([BRIDGE]),
    package_dir=ROOTS,
    packages=[
        f"{package}.{sub}" if sub else package
        for package, folder in ROOTS.items()
        for sub in ["", *find_packages(folder)]
    ],
)
