"""examples/host_c/host.c: a C host built with the system compiler against the ONNX Runtime
shared library of the onnxruntime wheel, running demo:afn on the C++ custom-op library
rtdenoise_ops with its state fed back and every buffer through the library's C input guard
(rtdenoise_guard.h), matches `Denoiser` within 1e-5 over the committed sequence, and over it
with frames polluted by NaN, +-Inf, out-of-range values, fireflies and a missing albedo pass
(the same guard counts and history restarts, a finite output). It is given only the frame
files and its command line: buffers, state, padding and names come from the model's metadata
and graph, and a model without that metadata is refused naming the key. Skipped, with the reason,
where the library was not built or there is no C compiler; the wheel's libonnxruntime is
required (it ships in the Linux wheels)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.bridge import native_cpp
from rtdenoise.runtime.sequences.frames import find_frames, read_frame
from rtdenoise.shipped import sample_sequences

HOST = Path(__file__).resolve().parents[1] / "examples" / "host_c" / "host.c"


def onnxruntime_library() -> Path:
    capi = Path(ort.__file__).parent / "capi"
    found = sorted(p for p in capi.glob("libonnxruntime.so*") if "providers" not in p.name)
    assert found, f"the onnxruntime wheel ships no libonnxruntime.so in {capi}"
    return found[-1]


def build_host(tmp_path: Path) -> Path:
    if sys.platform != "linux":
        pytest.skip("the C host is built and run on Linux")
    reason = native_cpp.unavailable_reason()
    if reason is not None:
        pytest.skip(f"the C++ library rtdenoise_ops was not built: {reason}")
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    # The wheel's file is libonnxruntime.so.1.<minor>.<patch>, its soname libonnxruntime.so.1,
    # and the wheel has no link of either name: the host links through links of its own.
    lib, libs = onnxruntime_library(), tmp_path / "lib"
    libs.mkdir()
    for name in ("libonnxruntime.so", "libonnxruntime.so.1"):
        (libs / name).symlink_to(lib)
    exe = tmp_path / "host"
    include = Path(native_cpp.__file__).parent / "native_ops"  # rtdenoise_guard.h
    res = subprocess.run(
        [cc, "-O2", "-Wall", "-Wextra", "-Werror", f"-I{include}", "-o", str(exe), str(HOST),
         f"-L{libs}", "-lonnxruntime", f"-Wl,-rpath,{libs}", "-ldl"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return exe


def run_host(
    exe: Path, model: Path | str, folder: Path, frames: int, h: int, w: int
) -> subprocess.CompletedProcess:
    """./host MODEL LIBRARY FOLDER FRAMES H W (examples/host_c/host.c's header)."""
    args = [str(model), str(native_cpp.library_path()), str(folder), str(frames), str(h), str(w)]
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=300)


def polluted(frames: list[dict[str, np.ndarray]]) -> list[dict[str, np.ndarray]]:
    """The frames cropped to 61 x 58 (padded to 64 x 64 by the model's multiple), with what a
    renderer may emit: NaN, +-Inf, colour above the half range and below 0, isolated
    fireflies (one on the last column, which padding before the guard would shield), a
    firefly pair, wild and NaN motion, depth +Inf, a frame without its albedo pass and one
    with NaN normals everywhere (zero once guarded: that pass is missing too)."""
    out = [{k: np.array(v[:, :61, :58], np.float32) for k, v in f.items()} for f in frames]
    f = out[1]
    f["color"][:, 5, 7] = np.nan
    f["color"][0, 10, 3] = np.inf
    f["color"][1, 3, 30] = -np.inf
    f["color"][:, 20, 20] = 1e6
    f["color"][2, 40, 9] = -4.0
    f["color"][:, 30, 57] = 5e4  # a firefly on the last column
    f["color"][:, 50, 12] = 3e4  # and one inside
    f["normal"][:, 4, 4] = np.nan
    f["depth"][0, 6, 6] = np.inf
    f["motion"][:, 12, 12] = 1e30
    f["motion"][1, 13, 40] = np.nan
    f["albedo"][:, 0, 0] = 1e5
    out[2]["color"][:, 33, 33:35] = 2e4  # two adjacent fireflies: kept
    out[3]["albedo"][:] = 0.0  # a missing pass: this frame and the next restart the history
    out[5]["normal"][:] = np.nan
    out[5]["color"][0] = -np.inf
    return out


def guard_lines(den: Denoiser, t: int) -> list[str]:
    """The line host.c prints for frame `t` from what `den.last_guard` says about it."""
    g = den.last_guard
    reset = int(t == 0 or g.reset is not None)
    if not (g.nonfinite_pixels or g.clamped or g.outliers or g.unusable or (reset and t > 0)):
        return []
    unusable = ",".join(g.unusable) or "-"
    return [
        f"frame {t}: nonfinite {g.nonfinite_pixels} clamped {sum(g.clamped.values())} "
        f"outliers {sum(g.outliers.values())} unusable {unusable} reset {reset}"
    ]


@pytest.mark.parametrize("pollution", ["clean", "polluted"])
def test_c_host_runs_afn_on_the_native_library_like_the_denoiser(tmp_path, pollution):
    exe = build_host(tmp_path)
    den = Denoiser("demo:afn")
    assert den.bridge == "native-cpp"
    frames = [read_frame(p).buffers for p in find_frames(sample_sequences()[0])][:8]
    if pollution == "polluted":
        frames = polluted(frames)
    h, w = frames[0]["color"].shape[-2:]
    for t, frame in enumerate(frames):  # unpadded: the host guards, then pads
        for b, data in frame.items():  # every buffer: the host picks what the model lists
            np.ascontiguousarray(data, np.float32).tofile(tmp_path / f"f{t}.{b}.f32")
    # no plan: the host reads buffers, state, padding and names from the model itself
    res = run_host(exe, den.source, tmp_path, len(frames), h, w)
    assert res.returncode == 0, res.stderr
    *guarded, last = res.stdout.strip().splitlines()
    assert last == f"{len(frames)} frames"
    expected_lines = []
    for t, frame in enumerate(frames):
        expected = den.process(frame)
        expected_lines += guard_lines(den, t)
        got = np.fromfile(tmp_path / f"out{t}.f32", np.float32).reshape(3, h, w)
        assert np.isfinite(got).all(), t
        err = float(np.abs(got - expected).max() / max(1.0, float(np.abs(expected).max())))
        assert err <= 1e-5, (t, err)
    assert guarded == expected_lines
    if pollution == "polluted":
        assert den.guard_totals.unusable_frames == 2 and den.guard_totals.outliers >= 2
        assert any("unusable albedo reset 1" in line for line in guarded)


@pytest.mark.parametrize(
    ("strip", "named"),
    [
        ("all", "metadata key rtdenoise.contract missing"),
        ("rtdenoise.state", "metadata key rtdenoise.state missing"),
        ("bad-state", 'metadata rtdenoise.state[1] has no key "channels"'),
        ("bad-margin", 'metadata rtdenoise.edge_margin is "-2", not an integer in 0..256'),
    ],
)
def test_c_host_refuses_a_model_without_its_metadata(tmp_path, strip, named):
    """A model file without (some of) its rtdenoise metadata: the host exits with status 2
    and one line naming the key, before reading any frame."""
    onnx = pytest.importorskip("onnx")
    exe = build_host(tmp_path)
    source = Denoiser("demo:afn").source
    model = onnx.load(str(source))
    props = {p.key: p.value for p in model.metadata_props}
    if strip == "all":
        props = {}
    elif strip == "bad-state":
        state = json.loads(props["rtdenoise.state"])
        del state[1]["channels"]
        props["rtdenoise.state"] = json.dumps(state)
    elif strip == "bad-margin":
        props["rtdenoise.edge_margin"] = "-2"
    else:
        del props[strip]
    del model.metadata_props[:]
    for key, value in props.items():
        model.metadata_props.add(key=key, value=value)
    path = tmp_path / "stripped.onnx"
    onnx.save(model, str(path))
    res = run_host(exe, path, tmp_path, 1, 8, 8)
    assert res.returncode == 2, (res.stdout, res.stderr)
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith(f"{path}: {named}"), res.stderr
    assert not list(tmp_path.glob("out*.f32"))


def test_c_host_applies_an_edge_margin_like_the_denoiser(tmp_path):
    """demo:afn given `rtdenoise.edge_margin` = 7 (an optional key): the host repeats 7 edge
    pixels on every side before padding to the multiple and reads the frame back from (7, 7),
    as `Denoiser` does, over 5 frames with state; the output differs from the model's without
    the margin, so a margin ignored or cropped from the wrong corner fails."""
    onnx = pytest.importorskip("onnx")
    exe = build_host(tmp_path)
    model = onnx.load(str(Denoiser("demo:afn").source))
    model.metadata_props.add(key="rtdenoise.edge_margin", value="7")
    path = tmp_path / "margin.onnx"
    onnx.save(model, str(path))
    den, without = Denoiser(path), Denoiser("demo:afn")
    assert den.edge_margin == 7 and den.bridge == "native-cpp"
    frames = [read_frame(p).buffers for p in find_frames(sample_sequences()[0])][:5]
    frames = [{k: np.array(v[:, :61, :58], np.float32) for k, v in f.items()} for f in frames]
    for t, frame in enumerate(frames):
        for b, data in frame.items():
            data.tofile(tmp_path / f"f{t}.{b}.f32")
    res = run_host(exe, path, tmp_path, len(frames), 61, 58)
    assert res.returncode == 0, res.stderr
    for t, frame in enumerate(frames):
        expected, plain = den.process(frame), without.process(frame)
        got = np.fromfile(tmp_path / f"out{t}.f32", np.float32).reshape(3, 61, 58)
        scale = max(1.0, float(np.abs(expected).max()))
        assert float(np.abs(got - expected).max()) / scale <= 1e-5, t
        assert float(np.abs(got - plain).max()) / scale > 1e-4, t
