"""ONNX Runtime's blocked (NCHWc) conv layout: what it inserts, and what it is worth.

For each model: lists the layout nodes ORT's optimiser put in the session's graph (NCHWc
convs, ReorderInput/ReorderOutput and what forces each reorder: the op that consumes a
ReorderOutput or produces a ReorderInput's source), then times whole frames (fast path, state
carried, synthetic frames) of session variants interleaved (A B C A B C ...), and sums ORT's
profiler (`SessionOptions.enable_profiling`) per op type per frame for each variant:

- `default`: ORT_ENABLE_ALL (what `Denoiser` runs);
- `no-nchwc`: the same with `disabled_optimizers=["NchwcTransformer"]` (plain NCHW convs);
- `extended`: ORT_ENABLE_EXTENDED (no layout transformers at all);
- `padded` (with `--pad 8`): ORT_ENABLE_ALL on the model with its conv chains' hidden widths
  zero-padded to a multiple of 8 (same outputs; WSKP's width 14 -> 16 becomes NCHWc).

    python benchmarks/nchwc.py --model demo:afn --model demo:wskp --size 1280x720 --pad 8
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import sys
import tempfile
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402

from rtdenoise.runtime import (  # noqa: E402
    Denoiser,
    bridge,  # noqa: E402
    resolve_model,
)
from rtdenoise.runtime.layout import with_layout  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402
from rtdenoise.runtime.session import ALLOW_SPINNING  # noqa: E402
from rtdenoise.runtime.static_check import custom_op_types  # noqa: E402

VARIANTS = {
    "default": ({}, ort.GraphOptimizationLevel.ORT_ENABLE_ALL),
    "no-nchwc": ({"disabled_optimizers": ["NchwcTransformer"]}, None),
    "extended": ({}, ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED),
}


def options(level, profile: str | None = None, optimized: str | None = None, ops=None):
    so = ort.SessionOptions()
    so.add_session_config_entry(ALLOW_SPINNING, "0")
    if level is not None:
        so.graph_optimization_level = level
    if profile:
        so.enable_profiling = True
        so.profile_file_prefix = profile
    if optimized:
        so.optimized_model_filepath = optimized
    bridge.register_fast_kernels(so, None, ops)  # the bridge Denoiser picks for these ops
    return so


def layout_report(path: str) -> str:
    """NCHWc nodes of the optimised graph and what each reorder sits next to."""
    tmp = os.path.join(tempfile.mkdtemp(), "opt.onnx")
    ort.InferenceSession(path, options(None, optimized=tmp))
    graph = onnx.load(tmp).graph
    producer = {o: n for n in graph.node for o in n.output}
    consumers = collections.defaultdict(list)
    for n in graph.node:
        for i in n.input:
            consumers[i].append(n.op_type)
    counts = collections.Counter(n.op_type for n in graph.node if n.domain == "com.microsoft.nchwc")
    convs = sum(
        n.op_type in ("Conv", "FusedConv") and n.domain != "com.microsoft.nchwc" for n in graph.node
    )
    lines = [f"  NCHWc nodes {dict(counts)}; NCHW convs {convs}"]
    for n in graph.node:
        if n.op_type == "ReorderOutput":
            lines.append(f"  ReorderOutput -> {consumers[n.output[0]]}")
        elif n.op_type == "ReorderInput":
            src = producer.get(n.input[0])
            lines.append(f"  ReorderInput <- {src.op_type if src else 'graph input'}")
    return "\n".join(lines)


def pad_conv_chain(path: str, multiple: int = 8) -> bytes:
    """The model with every hidden width of its Conv -> (activation) -> Conv chains zero-padded
    to a multiple of `multiple` (extra output channels with zero weights, and zero weights
    reading them): the same function, in a shape ORT's NchwcTransformer converts (it needs
    output channels divisible by the NCHWc block, 8 with AVX2, 16 with AVX-512)."""
    import numpy as np
    from onnx import numpy_helper

    m = onnx.load(path)
    inits = {i.name: i for i in m.graph.initializer}
    consumers = collections.defaultdict(list)
    for n in m.graph.node:
        for i in n.input:
            consumers[i].append(n)

    def next_convs(n):
        """The Convs reading `n`'s output directly or through one elementwise activation."""
        out = []
        for c in consumers[n.output[0]]:
            if c.op_type == "Conv":
                out.append(c)
            elif c.op_type in ("LeakyRelu", "Relu") and all(
                d.op_type == "Conv" for d in consumers[c.output[0]]
            ):
                out += consumers[c.output[0]]
            else:
                return []
        return out

    for n in [n for n in m.graph.node if n.op_type == "Conv" and n.input[1] in inits]:
        w = numpy_helper.to_array(inits[n.input[1]])
        nxt = next_convs(n)
        pad = -w.shape[0] % multiple
        if not pad or not nxt or len(n.input) > 2 or any(c.input[1] not in inits for c in nxt):
            continue
        inits[n.input[1]].CopyFrom(
            numpy_helper.from_array(
                np.concatenate([w, np.zeros((pad,) + w.shape[1:], w.dtype)]), n.input[1]
            )
        )
        for c in nxt:
            v = numpy_helper.to_array(inits[c.input[1]])
            z = np.zeros((v.shape[0], pad) + v.shape[2:], v.dtype)
            inits[c.input[1]].CopyFrom(
                numpy_helper.from_array(np.concatenate([v, z], 1), c.input[1])
            )
    del m.graph.value_info[:]  # the padded widths no longer match the recorded shapes
    return m.SerializeToString()


def session_denoiser(model: str, kwargs: dict, level, profile: str | None = None) -> Denoiser:
    """A Denoiser of `model` whose session is made again with `level` (and `profile`): the
    same fast-kernel bridge and conv forms (runtime/layout.py) as Denoiser picks."""
    den = Denoiser(model, fast_kernels=True)
    source = kwargs.pop("source", str(resolve_model(model)))
    data = source if isinstance(source, bytes) else open(source, "rb").read()
    data = with_layout(data, den.layout == "nchwc16") or data
    opts = options(level, profile, ops=custom_op_types(data))
    den._session = ort.InferenceSession(data, opts, **kwargs)
    den._binding = den._session.io_binding()
    return den


def profile_per_op(den: Denoiser) -> dict[str, float]:
    events = json.load(open(den._session.end_profiling()))
    runs = sum(e.get("cat") == "Session" and e["name"] == "model_run" for e in events)
    per_op: dict[str, float] = collections.defaultdict(float)
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per_op[e["args"]["op_name"]] += e["dur"] / 1e3 / max(runs, 1)
    return dict(per_op)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", action="append")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument(
        "--pad",
        type=int,
        default=0,
        help="also time the model with conv widths zero-padded to this multiple",
    )
    args = ap.parse_args(argv)
    tune_allocator()
    w, h = (int(v) for v in args.size.split("x"))
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}")
    print(f"# {' '.join(sys.argv)}")
    for model in args.model or ["demo:afn", "demo:wskp"]:
        print(f"\n## {model} {w}x{h}\n{layout_report(str(resolve_model(model)))}")
        variants = dict(VARIANTS)
        if args.pad:
            padded = pad_conv_chain(str(resolve_model(model)), args.pad)
            variants["padded"] = ({"source": padded}, None)
        dens = {n: session_denoiser(model, dict(kw), lv) for n, (kw, lv) in variants.items()}
        frames = synthetic_frames(next(iter(dens.values())).required_buffers, 4, h, w)
        times: dict[str, list[float]] = {n: [] for n in dens}
        for r in range(args.rounds + 1):
            for n, den in dens.items():
                t0 = time.perf_counter()
                den.process(frames[r % 4])
                if r:
                    times[n].append((time.perf_counter() - t0) * 1e3)
        if args.pad:
            ref = dens["default"].process(frames[0])
            diff = abs(dens["padded"].process(frames[0]) - ref).max() / abs(ref).max()
            print(f"  padded vs default: max relative difference {diff:.1e}")
        base = statistics.median(times["default"])
        for n, t in times.items():
            m = statistics.median(t)
            print(f"| {n} | {m:.0f} ({min(t):.0f}-{max(t):.0f}) | x{m / base:.2f} |")
        # the profiler slows a run: profile each variant separately, 3 frames each, in turn
        prof_dens = {
            n: session_denoiser(model, kw, lv, os.path.join(tempfile.mkdtemp(), n))
            for n, (kw, lv) in variants.items()
        }
        for r in range(4):
            for den in prof_dens.values():
                den.process(frames[r])
        profiles = {n: profile_per_op(d) for n, d in prof_dens.items()}
        ops = sorted(profiles["default"], key=lambda o: -profiles["default"][o])
        ops += sorted({o for p in profiles.values() for o in p} - set(ops))
        head = "\n| op (ms per frame, profiler, incl. warm-up frame) | "
        print(head + " | ".join(profiles) + " |")
        for op in ops:
            cells = [f"{profiles[n].get(op, 0.0):.1f}" for n in profiles]
            if max(profiles[n].get(op, 0.0) for n in profiles) >= 1.0:
                print(f"| {op} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
