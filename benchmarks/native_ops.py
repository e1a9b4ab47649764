"""The C++ library rtdenoise_ops (`native-cpp`) vs the numba kernels (`native` bridge), one
interleaved run: every op the library holds at each size, and whole frames of demo models.

Ops: a single-op model per op (default attributes, the spec's example inputs for a
(1, 3, H, W) image), one ONNX Runtime session per path; each round runs the numba session
then the C++ one (A B A B ...), after warm-up runs (numba compiles, or loads its cache, on the
first). Models: `Denoiser(model, fast_kernels="native-cpp")` and
`Denoiser(model, fast_kernels="native")` on the same synthetic frames, state carried,
one frame each in turn with a 100 ms pause after each (as revision_ab.py). Prints markdown
rows: median (min-max) ms of each path and the ratio numba / C++ (> 1: C++ faster).

    python benchmarks/native_ops.py --size 320x240 --size 1280x720 --model demo:afn
    python benchmarks/native_ops.py --op AffinityFilter --op CrossRegression --model demo:crossreg

Models run at 720p and larger when several sizes are given (every size when one is), each
path asked for by name (`fast_kernels="native-cpp"` and `"native"`).

`--first-frame MODEL` adds a fresh process per path: import and load, the first frame and the
tenth at the first size (numba loads its on-disk cache of compiled kernels, or compiles, on
the first frame; the C++ library has nothing to compile).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402

from rtdenoise.export import ops as eops  # noqa: E402
from rtdenoise.ops import get_spec  # noqa: E402
from rtdenoise.runtime import Denoiser  # noqa: E402
from rtdenoise.runtime import bridge as fast_bridge  # noqa: E402
from rtdenoise.runtime.bridge import native_cpp  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402


def op_session(op: str, attrs: dict, bridge: str) -> ort.InferenceSession:
    model = eops.single_op_model(op, None, attrs, with_function=False)
    so = ort.SessionOptions()
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    fast_bridge.register_fast_kernels(so, bridge, [op])
    return ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])


def summary(times: list[float]) -> str:
    return f"{statistics.median(times):.2f} ({min(times):.2f}-{max(times):.2f})"


def bench_op(op: str, h: int, w: int, rounds: int) -> str:
    spec = get_spec(op)
    attrs = dict(spec.default_attrs)
    inputs = spec.example_inputs((1, 3, h, w), attrs, np.random.default_rng(0))
    feed = dict(zip(spec.input_names, inputs, strict=True))
    paths = {"numba": op_session(op, attrs, "native"), "cpp": op_session(op, attrs, "native-cpp")}
    times: dict[str, list[float]] = {k: [] for k in paths}
    outs = {}
    for name, sess in paths.items():  # warm-up: numba compiles or loads its cache here
        for _ in range(2):
            outs[name] = sess.run(None, feed)
    diff = max(
        float(np.abs(a - b).max() / max(1.0, float(np.abs(b).max())))
        for a, b in zip(outs["cpp"], outs["numba"], strict=True)
    )
    for _ in range(rounds):
        for name, sess in paths.items():
            t0 = time.perf_counter()
            sess.run(None, feed)
            times[name].append((time.perf_counter() - t0) * 1e3)
    ratio = statistics.median(times["numba"]) / statistics.median(times["cpp"])
    return (
        f"| {op} | {w}x{h} | {summary(times['numba'])} | {summary(times['cpp'])} | "
        f"{ratio:.2f} | {diff:.1e} |"
    )


def bench_model(model: str, h: int, w: int, rounds: int, pause: float) -> str:
    from rtdenoise.runtime.errors import InputError

    try:
        dens = {
            "numba": Denoiser(model, fast_kernels="native"),
            "cpp": Denoiser(model, fast_kernels="native-cpp"),
        }
    except InputError as exc:
        return f"| {model} | {w}x{h} | - | {exc} | | |"
    frames = synthetic_frames(dens["cpp"].required_buffers, 4, h, w)
    for den in dens.values():  # warm-up frame (numba compiles or loads its cache)
        den.process(frames[0])
        den.reset()
    times: dict[str, list[float]] = {k: [] for k in dens}
    diff = 0.0
    for i in range(rounds):
        outs = {}
        for name, den in dens.items():
            t0 = time.perf_counter()
            outs[name] = den.process(frames[i % len(frames)])
            times[name].append((time.perf_counter() - t0) * 1e3)
            time.sleep(pause)
        diff = max(diff, float(np.abs(outs["cpp"] - outs["numba"]).max()))
    ratio = statistics.median(times["numba"]) / statistics.median(times["cpp"])
    return (
        f"| {model} (frame) | {w}x{h} | {summary(times['numba'])} | {summary(times['cpp'])} | "
        f"{ratio:.2f} | {diff:.1e} |"
    )


FIRST = r"""
import json, sys, time
t0 = time.perf_counter()
from rtdenoise.runtime import Denoiser
from rtdenoise.runtime.sequences.synthetic import synthetic_frames
den = Denoiser(sys.argv[1], fast_kernels=sys.argv[2])
frames = synthetic_frames(den.required_buffers, 4, int(sys.argv[3]), int(sys.argv[4]))
t1 = time.perf_counter()
times = []
for i in range(10):
    t = time.perf_counter()
    den.process(frames[i % 4])
    times.append((time.perf_counter() - t) * 1e3)
print(json.dumps({"bridge": den.bridge, "load_ms": (t1 - t0) * 1e3, "first_ms": times[0],
                  "tenth_ms": times[9]}))
"""


def first_frames(model: str, h: int, w: int) -> list[str]:
    """A fresh process per path: import + load, then the first and the tenth frame (numba
    reads its on-disk cache of compiled kernels on the first, or compiles without one)."""
    import json
    import subprocess
    import sys

    rows = []
    for path in ("native", "native-cpp"):  # numba, then the C++ library (asked for by name)
        res = subprocess.run(
            [sys.executable, "-c", FIRST, model, path, str(h), str(w)],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        r = json.loads(res.stdout.strip().splitlines()[-1])
        rows.append(
            f"| {model} | {w}x{h} | {r['bridge']} | {r['load_ms']:.0f} | {r['first_ms']:.0f} | "
            f"{r['tenth_ms']:.0f} |"
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", action="append", default=[], help="WxH (repeatable)")
    parser.add_argument("--op", action="append", default=[], help="ops (default: all held)")
    parser.add_argument("--model", action="append", default=[], help="e.g. demo:afn")
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--model-rounds", type=int, default=10)
    parser.add_argument("--pause", type=float, default=0.1)
    parser.add_argument("--first-frame", action="append", default=[], help="model (repeatable)")
    args = parser.parse_args()
    reason = native_cpp.unavailable_reason()
    if reason:
        raise SystemExit(f"the C++ library is not built: {reason}")
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.size or ["320x240", "1280x720"]]
    ops = args.op or sorted(native_cpp.covered_ops())
    print(f"ORT {ort.__version__}, {os.cpu_count()} CPUs")
    print("| op / model | size | numba ms | C++ ms | numba / C++ | max rel. diff |")
    print("|---|---|---|---|---|---|")
    for w, h in sizes:
        for op in ops:
            print(bench_op(op, h, w, args.rounds), flush=True)
    for model in args.model:
        for w, h in sizes:
            if w * h >= 1280 * 720 or len(sizes) == 1:
                print(bench_model(model, h, w, args.model_rounds, args.pause), flush=True)
    for model in args.first_frame:
        w, h = sizes[0]
        print("\n| model | size | path | import + load ms | frame 1 ms | frame 10 ms |")
        print("|---|---|---|---|---|---|")
        for row in first_frames(model, h, w):
            print(row, flush=True)


if __name__ == "__main__":
    main()
