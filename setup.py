"""Map the top-level folders onto the one import package `rtdenoise` (docs/architecture.md).

`rtdenoise.<name>` is the folder `<name>/` for every name of `rtdenoise.SUBPACKAGES` (which a
checkout uses the same way: rtdenoise/__init__.py); every sub-package of a mapped folder is
found, so adding a package needs no edit here. All other metadata lives in pyproject.toml.

The one compiled part is the native custom-op bridge (runtime/bridge/_ort_bridge.c, a plain C
file against ONNX Runtime's C ABI): optional, so that an install without a C compiler still
works and runs the fast kernels through onnxruntime-extensions instead
(runtime/bridge/native.py).
"""

from setuptools import Extension, find_packages, setup

SUBPACKAGES = ("ops", "models", "export", "runtime", "cli", "datagen")  # = rtdenoise.SUBPACKAGES
ROOTS = {"rtdenoise": "rtdenoise"} | {f"rtdenoise.{name}": name for name in SUBPACKAGES}

BRIDGE = Extension(
    "rtdenoise.runtime.bridge._ort_bridge",
    sources=["runtime/bridge/_ort_bridge.c"],
    optional=True,
)

setup(
    ext_modules=[BRIDGE],
    package_dir=ROOTS,
    packages=[
        f"{package}.{sub}" if sub else package
        for package, folder in ROOTS.items()
        for sub in ["", *find_packages(folder)]
    ],
)
