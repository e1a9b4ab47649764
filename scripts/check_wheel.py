"""Check an installed rtdenoise wheel: every native part built in, no framework, the demo runs.

    python scripts/check_wheel.py PROJECT_DIR

Run with the interpreter of a venv holding only the wheel and its dependencies (cibuildwheel's
test step, scripts/build_release_wheel.sh), from any folder but the checkout. Checks:

- every Extension that PROJECT_DIR/setup.py declares (found in its source, so a new one is
  checked without an edit here) imports from the install as a compiled module;
- rtdenoise itself comes from the install, and neither a deep learning framework nor numba
  (the `numba` extra) is installed;
- every shipped demo runs two frames on the C++ library (`native-cpp`), with no warning;
- `denoise-run --demo` denoises the three bundled sequences on it.

Exits 1 with one line per failed check.
"""

from __future__ import annotations

import ast
import importlib.machinery
import importlib.util
import os
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path


def declared_extensions(setup_py: Path) -> list[str]:
    """The module names of the `Extension(...)` calls in setup.py (literal names only)."""
    names = []
    for node in ast.walk(ast.parse(setup_py.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        called = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
        if called != "Extension":
            continue
        arg = (
            node.args[0]
            if node.args
            else next((k.value for k in node.keywords if k.arg == "name"), None)
        )
        if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
            raise SystemExit(f"{setup_py}:{node.lineno}: an Extension without a literal name")
        names.append(arg.value)
    return names


def _installed_file(name: str) -> str | None:
    """The installed file of Extension `name`: a Python extension module, or a plain shared
    library (lib<last>.so / .dylib, <last>.dll) in its package folder (setup.py's BuildExt)."""
    spec = importlib.util.find_spec(name)
    if spec is not None and spec.origin:
        if spec.origin.endswith(tuple(importlib.machinery.EXTENSION_SUFFIXES)):
            return spec.origin
    package, _, last = name.rpartition(".")
    folder = Path(importlib.util.find_spec(package).origin).parent
    for file in (f"lib{last}.so", f"lib{last}.dylib", f"{last}.dll"):
        if (folder / file).is_file():
            return str(folder / file)
    return None


def demo_problems() -> list[str]:
    """Each shipped demo over two synthetic frames: a problem unless it ran on native-cpp,
    with finite outputs and no warning."""
    import numpy as np

    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.sequences.samples import sample_features_of
    from rtdenoise.runtime.sequences.synthetic import synthetic_frames
    from rtdenoise.shipped import MODELS_DIR

    demos = sorted(p.stem for p in MODELS_DIR.glob("*.onnx"))
    problems = [] if demos else [f"no demo model in {MODELS_DIR}"]
    for demo in demos:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            den = Denoiser(f"demo:{demo}")
            features = sample_features_of(den.config)
            frames = synthetic_frames(den.required_buffers, 2, 40, 56, sample_features=features)
            finite = all(np.isfinite(den.process(f)).all() for f in frames)
        if den.bridge != "native-cpp":
            problems.append(f"demo:{demo}'s custom ops run on {den.bridge!r}, not 'native-cpp'")
        if not finite:
            problems.append(f"demo:{demo} gave a non-finite output")
        problems += [f"demo:{demo} warned: {w.message}" for w in caught]
    return problems


def check(project: Path) -> list[str]:
    problems = []
    import rtdenoise

    if project.resolve() in Path(rtdenoise.__file__).resolve().parents:
        problems.append(f"rtdenoise imported from the checkout ({rtdenoise.__file__})")
    extensions = declared_extensions(project / "setup.py")
    if not extensions:
        problems.append(f"{project / 'setup.py'} declares no Extension")
    for name in extensions:
        origin = _installed_file(name)
        if origin is None:
            problems.append(f"extension {name}: not in the installed wheel")
    extras = ("torch", "onnx", "onnxscript", "numba", "onnxruntime_extensions")
    pulled = [m for m in extras if importlib.util.find_spec(m)]
    if pulled:
        problems.append(f"the base install pulled in {', '.join(pulled)}")
    problems += demo_problems()
    scripts = Path(sys.executable).parent
    command = scripts / ("denoise-run.exe" if os.name == "nt" else "denoise-run")
    with tempfile.TemporaryDirectory() as out:
        proc = subprocess.run(
            [str(command), "--demo", "-o", out], capture_output=True, text=True, timeout=900
        )
        outputs = len(list(Path(out).glob("seq_*/frame_*.exr")))
    if proc.returncode != 0 or "over 3 sequences: mean PSNR" not in proc.stdout:
        problems.append(f"denoise-run --demo failed ({proc.returncode}): {proc.stderr[-2000:]}")
    elif outputs != 24:
        problems.append(f"denoise-run --demo wrote {outputs} frames, not 24")
    elif proc.stdout.count("custom ops: native-cpp") != 3:
        problems.append("denoise-run --demo ran a sequence off the C++ library: " + proc.stdout)
    warned = [line for line in proc.stderr.splitlines() if line.startswith(("warning", "error"))]
    if warned:
        problems.append(f"denoise-run --demo warned: {warned[0]}")
    if not problems:
        print(proc.stdout.strip().splitlines()[-1])
    return problems


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    problems = check(Path(sys.argv[1]))
    for p in problems:
        print(f"check_wheel: {p}", file=sys.stderr)
    if not problems:
        print("check_wheel: ok")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
