"""Where a fast kernel's time goes between "standalone" and "inside ONNX Runtime".

For every custom-op node a model runs, the script records the node's real inputs and
attributes on one frame (`Denoiser`, fast path, synthetic frames), then times each call in its
layers, interleaved round by round (A B C D E A B C D E ...), medians over rounds:

- `driver`: the numba driver on preallocated outputs (the computation alone);
- `kernel`: `FastKernel(*inputs)` (spec checks, output allocation, the driver);
- `hook`:   `extensions._array_hook` (what the C++ bridge calls: attribute casting, the kernel,
            the result tuple);
- `ort`:    a one-node ONNX Runtime session with the fast kernels (the whole PyOp path:
            the C++ bridge copies every input into a new numpy array, takes the GIL, calls the
            hook, allocates the ORT output and copies the result into it);
- `copies`: what that bridge's copies cost if done in numpy: a fresh array + copy per input,
            and one copy per output into a fresh array.

`ort - hook` is the bridge; compare it with `copies`. Also prints, per op, the node time in the
whole model from ORT's profiler (`enable_profiling`), per frame.

    python benchmarks/pyop_overhead.py --model demo:wskp --size 1280x720
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections import defaultdict

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import onnxruntime as ort  # noqa: E402

from rtdenoise.runtime import (  # noqa: E402
    Denoiser,
    bridge,  # noqa: E402
    resolve_model,
)
from rtdenoise.runtime.bridge import extensions  # noqa: E402
from rtdenoise.runtime.kernels import KERNELS  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402

LAYERS = ("driver", "kernel", "hook", "ort", "copies")


def record_calls(model: str, h: int, w: int) -> list[tuple[str, int, list, dict]]:
    """(op name, opdef id, inputs, raw attributes) of every custom-op call of frame 2."""
    calls: list = []
    recording = [False]

    def recorder(k_id, feed, attributes):
        if recording[0]:
            name = extensions._ortx_ocos.Opdef._odlist[k_id].op_type.split("::")[-1]
            calls.append((name, k_id, [np.array(a) for a in feed], dict(attributes)))
        return extensions._array_hook(k_id, feed, attributes)

    den = Denoiser(model)
    extensions.PyCustomOpDef.install_hooker(recorder)
    try:
        frames = synthetic_frames(den.required_buffers, 3, h, w)
        den.process(frames[0])
        den.process(frames[1])
        recording[0] = True
        den.process(frames[2])
    finally:
        extensions.PyCustomOpDef.install_hooker(extensions._array_hook)
    return calls


def profile_nodes(model: str, h: int, w: int, frames: int = 3) -> dict[str, float]:
    """ms per frame of each op type in the whole model (ORT profiler, fast path)."""
    den = Denoiser(model)
    so = ort.SessionOptions()
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.enable_profiling = True
    so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), "prof")
    bridge.register_fast_kernels(so)
    den._session = ort.InferenceSession(str(resolve_model(model)), so)
    den._binding = den._session.io_binding()
    seq = synthetic_frames(den.required_buffers, frames + 1, h, w)
    den.process(seq[0])
    den._session.end_profiling()
    den._session = ort.InferenceSession(str(resolve_model(model)), so)
    den._binding = den._session.io_binding()
    den.reset()
    for f in seq[1:]:
        den.process(f)
    events = json.load(open(den._session.end_profiling()))
    per_op: dict[str, float] = defaultdict(float)
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per_op[e["args"]["op_name"]] += e["dur"] / 1e3 / frames
    return dict(per_op)


def layer_calls(name: str, k_id: int, inputs: list, attrs: dict) -> dict:
    from rtdenoise.export.ops import single_op_model

    kernel = KERNELS[name]
    ints = {k: int(v) for k, v in attrs.items()}
    outs = kernel(*inputs, **ints)
    outs = outs if isinstance(outs, tuple) else (outs,)
    pre = [np.empty_like(o) for o in outs]
    model = single_op_model(name, [list(a.shape) for a in inputs], ints).SerializeToString()
    so = ort.SessionOptions()
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    bridge.register_fast_kernels(so)
    sess = ort.InferenceSession(model, so)
    feed = dict(zip(kernel.spec.input_names, inputs, strict=True))

    def copies() -> None:
        for a in inputs:
            np.copyto(np.empty_like(a), a)
        for o in outs:
            np.copyto(np.empty_like(o), o)

    return {
        "driver": lambda: kernel.driver(*inputs, *pre, **ints),
        "kernel": lambda: kernel(*inputs, **ints),
        "hook": lambda: extensions._array_hook(k_id, list(inputs), dict(attrs)),
        "ort": lambda: sess.run(None, feed),
        "copies": copies,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="demo:wskp")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--rounds", type=int, default=7)
    args = ap.parse_args(argv)
    tune_allocator()
    extensions.install_array_hook()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}")
    print(f"# {' '.join(sys.argv)}")
    calls = record_calls(args.model, h, w)
    layers = [layer_calls(*c) for c in calls]
    times: list[dict[str, list[float]]] = [{k: [] for k in LAYERS} for _ in calls]
    for r in range(args.rounds + 1):
        for i, fns in enumerate(layers):
            for k in LAYERS:
                t0 = time.perf_counter()
                fns[k]()
                if r:
                    times[i][k].append((time.perf_counter() - t0) * 1e3)
    print("| op | inputs MB | outputs MB | " + " | ".join(LAYERS) + " | ort - hook |")
    print("|---|---:|---:|" + "---:|" * (len(LAYERS) + 1))
    totals = defaultdict(float)
    for (name, _k, inputs, attrs), t in zip(calls, times, strict=True):
        kernel = KERNELS[name]
        outs = kernel(*inputs, **{k: int(v) for k, v in attrs.items()})
        outs = outs if isinstance(outs, tuple) else (outs,)
        med = {k: statistics.median(v) for k, v in t.items()}
        for k, v in med.items():
            totals[k] += v
        cells = [f"{med[k]:.1f} ({min(t[k]):.1f}-{max(t[k]):.1f})" for k in LAYERS]
        mb_in = sum(a.nbytes for a in inputs) / 1e6
        mb_out = sum(o.nbytes for o in outs) / 1e6
        label = f"{name} {dict((k, int(v)) for k, v in attrs.items())}"
        print(
            f"| {label} | {mb_in:.1f} | {mb_out:.1f} | "
            + " | ".join(cells)
            + f" | {med['ort'] - med['hook']:.1f} |"
        )
    print(
        "| all calls (sum of medians) | | | "
        + " | ".join(f"{totals[k]:.1f}" for k in LAYERS)
        + f" | {totals['ort'] - totals['hook']:.1f} |"
    )
    prof = profile_nodes(args.model, h, w)
    print("\nORT profiler, whole model, ms per frame (fast path, no spinning):")
    for op, ms in sorted(prof.items(), key=lambda x: -x[1])[:12]:
        print(f"  {op:24s} {ms:8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
