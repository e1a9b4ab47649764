"""examples/host_c/host.c: a C host built with the system compiler against the ONNX Runtime
shared library of the onnxruntime wheel, running demo:afn on the C++ custom-op library
rtdenoise_ops with its state fed back, matches `Denoiser` within 1e-5 over the committed
sequence. Skipped, with the reason, where the library was not built or there is no C
compiler; the wheel's libonnxruntime is required (it ships in the Linux wheels)."""

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
    res = subprocess.run(
        [cc, "-O2", "-Wall", "-o", str(exe), str(HOST), f"-L{libs}", "-lonnxruntime",
         f"-Wl,-rpath,{libs}", "-ldl"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return exe


def test_c_host_runs_afn_on_the_native_library_like_the_denoiser(tmp_path):
    exe = build_host(tmp_path)
    den = Denoiser("demo:afn")
    assert den.bridge == "native-cpp"
    meta = den.session.get_modelmeta().custom_metadata_map
    buffers = json.loads(meta["rtdenoise.inputs"])["buffers"]
    states = json.loads(meta["rtdenoise.state"])
    pad = int(meta["rtdenoise.pad_multiple"])
    inputs = {i.name for i in den.session.get_inputs()}
    frames = [read_frame(p).buffers for p in find_frames(sample_sequences()[0])][:8]
    h, w = frames[0][buffers[0]].shape[-2:]
    hp, wp = -(-h // pad) * pad, -(-w // pad) * pad
    # the plan: what a host reads from the metadata (docs/contract.md, "Driving a model")
    lines = [f"model {den.source}", f"library {native_cpp.library_path()}", f"frames {len(frames)}"]
    ins = [(b, (1, frames[0][b].shape[0], hp, wp)) for b in buffers]
    if "reset" in inputs:
        ins.append(("reset", ()))
    lines.append(f"inputs {len(ins)}")
    lines += [f"{n} {len(s)} {' '.join(map(str, s))}".strip() for n, s in ins]
    lines.append(f"state {len(states)}")
    for s in states:
        shape = (1, s["channels"], *(s.get("size") or (hp // s["scale"], wp // s["scale"])))
        lines.append(f"state.{s['name']} {len(shape)} {' '.join(map(str, shape))}")
    lines.append(f"output output 4 1 3 {hp} {wp}")
    (tmp_path / "plan.txt").write_text("\n".join(lines) + "\n")
    for t, frame in enumerate(frames):
        for b in buffers:
            a = np.asarray(frame[b], np.float32)
            a = np.pad(a, [(0, 0), (0, hp - h), (0, wp - w)], mode="edge")
            np.ascontiguousarray(a, np.float32).tofile(tmp_path / f"f{t}.{b}.f32")
    res = subprocess.run(
        [str(exe), str(tmp_path / "plan.txt"), str(tmp_path)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == f"{len(frames)} frames"
    for t, frame in enumerate(frames):
        expected = den.process(frame)
        got = np.fromfile(tmp_path / f"out{t}.f32", np.float32).reshape(3, hp, wp)[:, :h, :w]
        err = float(np.abs(got - expected).max() / max(1.0, float(np.abs(expected).max())))
        assert err <= 1e-5, (t, err)
