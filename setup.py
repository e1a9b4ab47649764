"""Map the top-level folders onto the one import package `rtdenoise` (docs/architecture.md).

`rtdenoise.<name>` is the folder `<name>/`; every sub-package of a mapped folder is found, so
adding a package needs no edit here. All other metadata lives in pyproject.toml.

The one compiled part is the native custom-op bridge (runtime/_ort_bridge.c, a plain C file
against ONNX Runtime's C ABI): optional, so that an install without a C compiler still works and
runs the fast kernels through onnxruntime-extensions instead (runtime/native_ops.py).
"""

from setuptools import Extension, find_packages, setup

ROOTS = {
    "rtdenoise": "rtdenoise",
    "rtdenoise.ops": "ops",
    "rtdenoise.models": "models",
    "rtdenoise.export": "export",
    "rtdenoise.runtime": "runtime",
    "rtdenoise.cli": "cli",
    "rtdenoise.datagen": "datagen",
}

BRIDGE = Extension(
    "rtdenoise.runtime._ort_bridge",
    sources=["runtime/_ort_bridge.c"],
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
