"""Without numba (the `numba` extra, pyproject.toml) every shipped demo runs on the C++ library
rtdenoise_ops, with no warning and the numba path's numbers; with neither (RTDENOISE_NATIVE_OPS=0)
the custom ops run their portable ONNX bodies, with one warning per process, and denoise-run
still works; without onnxruntime-extensions the native bridge still runs the numba kernels."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from progress_lines import other_lines
from shipped_demos import SHIPPED_DEMOS
from without_modules import without

from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.runtime.sequences.frames import find_frames, read_frame
from rtdenoise.runtime.sequences.samples import sample_features_of, samples_from_buffers
from rtdenoise.shipped import MODELS_DIR, sample_sequences

SCRIPT = """
from rtdenoise.cli.run import main
sys.argv[1:] = sys.argv[2:]
main()
"""
FRAMES = 4  # of the committed sequence seq_000 (64x64), state carried from frame to frame


@pytest.mark.parametrize(
    "missing, cpp", [("onnxruntime_extensions", "0"), ("numba", "1"), ("numba", "0")]
)
def test_denoise_run_without_a_kernel_library(tmp_path, missing, cpp):
    """demo:affinity through denoise-run, which says on its timing line which path ran: with
    the C++ library off, the native bridge runs the numba kernels without
    onnxruntime-extensions; without numba, the library, or with neither the portable bodies."""
    seq = sample_sequences()[0]
    args = [str(seq / "frame_000[0-2].exr"), "-o", str(tmp_path), "--model", "demo:affinity"]
    proc = subprocess.run(
        [sys.executable, "-c", without(missing) + SCRIPT, missing, *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=os.environ | {native_cpp.ENV_SWITCH: cpp},
    )
    assert proc.returncode == 0, proc.stderr
    lines = other_lines(proc.stderr)
    if missing == "onnxruntime_extensions":  # the native bridge needs none of it
        assert lines == []
        assert "custom ops: native (numba kernels)" in proc.stdout
    elif cpp == "1" and native_cpp.available():  # the C++ library needs no numba
        assert lines == []
        assert "custom ops: native-cpp" in proc.stdout
    else:
        assert len(lines) == 1 and lines[0].startswith("warning: fast kernels unavailable"), lines
        assert missing in lines[0] and "portable ONNX bodies" in lines[0]
        assert "custom ops: portable ONNX bodies" in proc.stdout
    assert sorted(p.name for p in tmp_path.glob("*.exr")) == [f"frame_000{i}.exr" for i in range(3)]
    assert "PSNR" in proc.stdout


# Runs demo:<name> for each name over the frames of an .npz each, saves the outputs; prints the
# bridges, the warnings and whether numba or onnxruntime-extensions was imported.
DEMO_SCRIPT = """
import json, warnings
import numpy as np
from rtdenoise.runtime import Denoiser

folder, demos = sys.argv[1], sys.argv[2:]
bridges = []
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")  # every warning given is counted
    for demo in demos:
        data = np.load(f"{folder}/{demo}.in.npz")
        frames = [{k.split("/")[1]: data[k] for k in data if k.startswith(f"{t}/")}
                  for t in range(len({k.split("/")[0] for k in data}))]
        den = Denoiser(f"demo:{demo}")
        np.save(f"{folder}/{demo}.out.npy", np.stack([den.process(f) for f in frames]))
        bridges.append(den.bridge)
print(json.dumps({
    "bridges": bridges,
    "warnings": [f"{w.category.__name__}: {w.message}" for w in caught],
    "imported": sorted(m for m in ("numba", "onnxruntime_extensions") if sys.modules.get(m)),
}))
"""


def demo_frames(den: Denoiser) -> list[dict[str, np.ndarray]]:
    """FRAMES frames of seq_000 with the buffers `den` needs (affinity's per-sample input made
    from the pixel buffers)."""
    frames = [dict(read_frame(p).buffers) for p in find_frames(sample_sequences()[0])[:FRAMES]]
    if "samples" in den.required_buffers:
        for f in frames:
            f["samples"] = samples_from_buffers(f, sample_features_of(den.config))
    return frames


def run_demos_without_numba(tmp_path, demos, env=None) -> tuple[dict, dict[str, np.ndarray]]:
    """`demos` run in a fresh interpreter without numba and onnxruntime-extensions, each over
    demo_frames; its report and demo -> the outputs, with the numba path's here beside them
    (demo -> (without, numba))."""
    expected = {}
    for demo in demos:
        den = Denoiser(f"demo:{demo}", fast_kernels="native")  # the numba kernels
        frames = demo_frames(den)
        expected[demo] = np.stack([den.process(f) for f in frames])
        np.savez(
            tmp_path / f"{demo}.in.npz",
            **{f"{t}/{k}": v for t, f in enumerate(frames) for k, v in f.items()},
        )
    proc = subprocess.run(
        [
            sys.executable, "-c", without("numba", "onnxruntime_extensions") + DEMO_SCRIPT,
            str(tmp_path), *demos,
        ],
        capture_output=True, text=True, timeout=300, env=os.environ | (env or {}),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    return report, {d: (np.load(tmp_path / f"{d}.out.npy"), expected[d]) for d in demos}


def relative_error(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.abs(got - want).max() / max(1.0, float(np.abs(want).max())))


def test_every_shipped_demo_runs_on_the_cpp_library_without_numba(tmp_path, monkeypatch):
    """The base install (no numba): each demo on native-cpp, as with numba installed, no
    warning, no numba imported, the numbers of the numba path within 1e-5 over FRAMES frames
    with state."""
    if not native_cpp.available():
        pytest.skip(f"the C++ library was not built: {native_cpp.unavailable_reason()}")
    monkeypatch.delenv(native_cpp.ENV_SWITCH, raising=False)
    assert set(SHIPPED_DEMOS) == {p.stem for p in MODELS_DIR.glob("*.onnx")}  # every shipped demo
    report, outputs = run_demos_without_numba(tmp_path, SHIPPED_DEMOS)
    assert report == {
        "bridges": ["native-cpp"] * len(SHIPPED_DEMOS),
        "warnings": [],
        "imported": [],
    }
    for demo, (got, want) in outputs.items():
        assert got.shape == want.shape == (FRAMES, 3, 64, 64), demo
        assert relative_error(got, want) <= 1e-5, demo


def test_without_numba_or_the_library_the_portable_bodies_run_with_one_warning(tmp_path):
    """RTDENOISE_NATIVE_OPS=0 and no numba: two models in one process run their portable
    bodies with ONE warning between them, naming what to install; within 1e-4 of the fast
    path."""
    report, outputs = run_demos_without_numba(
        tmp_path, ("wskp", "nbg"), env={native_cpp.ENV_SWITCH: "0"}
    )
    assert report["bridges"] == ["", ""] and report["imported"] == []
    assert len(report["warnings"]) == 1, report["warnings"]
    warning = report["warnings"][0]
    assert warning.startswith("RuntimeWarning: fast kernels unavailable: numba is not installed")
    assert "RTDENOISE_NATIVE_OPS=0" in warning and "portable ONNX bodies" in warning
    assert "pip install 'rtdenoise[numba]'" in warning and "C++17 compiler" in warning
    for demo, (got, want) in outputs.items():
        assert np.isfinite(got).all(), demo
        assert relative_error(got, want) <= 1e-4, demo


def test_a_numba_bridge_asked_for_without_numba_is_an_error_naming_the_extra(monkeypatch):
    from rtdenoise.runtime import bridge
    from rtdenoise.runtime.errors import InputError

    monkeypatch.setattr(bridge, "numba_installed", lambda: False)
    for name in bridge.NUMBA_BRIDGES:
        with pytest.raises(InputError, match=rf"fast_kernels='{name}': numba .*rtdenoise\[numba\]"):
            Denoiser("demo:afn", fast_kernels=name)
