"""Map the top-level folders onto the one import package `rtdenoise` (docs/architecture.md).

`rtdenoise.<name>` is the folder `<name>/` for every name of `rtdenoise.SUBPACKAGES` (which a
checkout uses the same way: rtdenoise/__init__.py); every sub-package of a mapped folder is
found, so adding a package needs no edit here. All other metadata lives in pyproject.toml.

Two compiled parts, both optional, so that an install without a compiler still works:

- the native custom-op bridge (runtime/bridge/_ort_bridge.c, a plain C file against ONNX
  Runtime's C ABI that calls the numba kernels; without it they run through
  onnxruntime-extensions, runtime/bridge/native.py);
- `rtdenoise_ops` (runtime/bridge/native_ops/, C++17, no Python inside): the ops' own kernels
  as an ONNX Runtime custom-op library that any host loads, installed as
  rtdenoise/runtime/bridge/librtdenoise_ops.so (.dylib, rtdenoise_ops.dll); without it the
  numba kernels run (runtime/bridge/native_cpp.py). Built as a plain shared library, not a
  Python module: `BuildExt` names the file and picks the flags (no -march: a wheel's x86-64
  baseline; kernels_common.h adds AVX2 and AVX-512 clones of each row loop, chosen at load).

A release wheel must carry every native part: with RTDENOISE_REQUIRE_EXTENSIONS=1 (set by
[tool.cibuildwheel] and scripts/build_release_wheel.sh) no extension is optional, so a compile
failure fails the build instead of shipping a wheel without it.
"""

import os
import sys

from setuptools import Extension, find_packages, setup
from setuptools.command.build_ext import build_ext

SUBPACKAGES = ("ops", "models", "export", "runtime", "cli", "datagen")  # = rtdenoise.SUBPACKAGES
ROOTS = {"rtdenoise": "rtdenoise"} | {f"rtdenoise.{name}": name for name in SUBPACKAGES}

BRIDGE = Extension(
    "rtdenoise.runtime.bridge._ort_bridge",
    sources=["runtime/bridge/_ort_bridge.c"],
    optional=True,
)

NATIVE_OPS = Extension(
    "rtdenoise.runtime.bridge.rtdenoise_ops",
    sources=[
        f"runtime/bridge/native_ops/{f}.cpp"
        for f in (
            "library",
            "kernels",
            "filters",
            "affinity",
            "crossreg",
            "crossreg_step",
            "conv_grad",
        )
    ],
    depends=[f"runtime/bridge/native_ops/{f}.h" for f in ("kernels", "kernels_common", "ort_abi")],
    language="c++",
    optional=True,
)
NATIVE_OPS.sources.append("runtime/bridge/native_ops/guard.cpp")  # C input guard: rtdenoise_guard.h
EXPORTS = ["RegisterCustomOps", "rtdenoise_ops_names", "rtdenoise_ops_set_threads",
           "rtdenoise_ops_abi"]  # fmt: skip


class BuildExt(build_ext):
    """build_ext that builds NATIVE_OPS as a plain shared library (lib<name>.so / .dylib,
    <name>.dll) with C++17 flags for the compiler at hand."""

    def get_ext_filename(self, fullname: str) -> str:
        # called with the full name and (distutils' get_ext_fullpath) with its last part
        if fullname not in (NATIVE_OPS.name, NATIVE_OPS.name.rpartition(".")[2]):
            return super().get_ext_filename(fullname)
        *package, name = fullname.split(".")
        file = {"win32": f"{name}.dll", "darwin": f"lib{name}.dylib"}.get(
            sys.platform, f"lib{name}.so"
        )
        return os.path.join(*package, file)

    def get_export_symbols(self, ext: Extension) -> list[str]:
        return EXPORTS if ext.name == NATIVE_OPS.name else super().get_export_symbols(ext)

    def build_extension(self, ext: Extension) -> None:
        if ext.name == NATIVE_OPS.name:
            if self.compiler.compiler_type == "msvc":
                ext.extra_compile_args = ["/std:c++17", "/O2", "/fp:precise", "/EHsc"]
            else:  # gcc, clang: no fused multiply-adds but where filters.cpp asks (as numba)
                ext.extra_compile_args = [
                    "-std=c++17", "-O3", "-ffp-contract=off", "-fno-math-errno",
                    "-fno-trapping-math", "-fvisibility=hidden", "-pthread",
                ]  # fmt: skip
                ext.extra_link_args = ["-pthread"]
        super().build_extension(ext)


def release_extensions(extensions: list[Extension]) -> list[Extension]:
    """`extensions`, none optional when RTDENOISE_REQUIRE_EXTENSIONS=1 (a release build)."""
    if os.environ.get("RTDENOISE_REQUIRE_EXTENSIONS") == "1":
        for ext in extensions:
            ext.optional = False
    return extensions


setup(
    cmdclass={"build_ext": BuildExt},
    ext_modules=release_extensions([BRIDGE, NATIVE_OPS]),
    package_dir=ROOTS,
    packages=[
        f"{package}.{sub}" if sub else package
        for package, folder in ROOTS.items()
        for sub in ["", *find_packages(folder)]
    ],
)
