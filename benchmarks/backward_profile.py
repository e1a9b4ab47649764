"""Where an online model's learning frame spends its time: ONNX Runtime's own profile of
learning and frozen frames (demo:crossreg, fast kernels, state fed back), the nodes a learning
frame runs that a frozen one does not (the backward pass and Adam under the learning If,
export/learning_branch.py), per op type and the costliest nodes, medians over the frames.

    python benchmarks/backward_profile.py --model demo:crossreg --size 1280x720 --frames 2

Frames alternate learn, freeze, learn, freeze, ... after one warm-up of each (the same
synthetic frames, each kind with its own state). A node's time is its kernel time
(`*_kernel_time` events); an If's own event (its branch's nodes and its overhead) is reported
apart, as `If (whole branch)`.
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

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before numba's OpenMP layer starts

import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402

from rtdenoise.runtime import bridge  # noqa: E402
from rtdenoise.runtime.contract import RESET, contract_from_session  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402
from rtdenoise.runtime.session import ALLOW_SPINNING, kernel_thread_count, resolve_model  # noqa: E402
from rtdenoise.runtime.static_check import custom_op_types  # noqa: E402


def profile(model: str, size: tuple[int, int], frames: int, threads: int | None):
    data = resolve_model(model).read_bytes()
    proto = onnx.load_from_string(data)
    so = ort.SessionOptions()
    if threads:
        so.intra_op_num_threads = threads
    # the model's ops: the default bridge for them (the C++ library where it holds them all),
    # as Denoiser picks it; with no ops named the numba kernels would run
    chosen = bridge.register_fast_kernels(so, None, custom_op_types(data))
    print(f"# fast kernels: {chosen}")
    so.add_session_config_entry(ALLOW_SPINNING, "0")
    so.enable_profiling = True
    so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), "ort")
    session = ort.InferenceSession(proto.SerializeToString(), so, ["CPUExecutionProvider"])
    contract = contract_from_session(session)
    h, w = size
    data = synthetic_frames(contract.buffer_names, 4, h, w)
    states = {}
    kinds = []
    walls: dict[str, list[float]] = defaultdict(list)
    for k in range(2 * (frames + 1)):
        freeze = float(k % 2)
        state = states.get(freeze) or {
            s.name: np.zeros(s.shape(h, w), np.float32) for s in contract.state
        }
        state["freeze"] = np.full_like(state["freeze"], freeze)
        frame = data[(k // 2) % len(data)]
        feed = {name: frame[name][None] for name in contract.buffer_names}
        feed[RESET] = np.array(1.0 if k < 2 else 0.0, np.float32)
        feed.update({s.input_name: state[s.name] for s in contract.state})
        t0 = time.perf_counter()
        with bridge.kernel_threads(chosen, kernel_thread_count((h, w), threads)):
            outs = session.run(None, feed)
        if k >= 2:
            walls["learn" if freeze == 0 else "frozen"].append((time.perf_counter() - t0) * 1e3)
        named = dict(zip([o.name for o in session.get_outputs()], outs, strict=True))
        states[freeze] = {s.name: named[s.output_name] for s in contract.state}
        kinds.append("learn" if freeze == 0 else "frozen")
    with open(session.end_profiling()) as fh:
        events = json.load(fh)
    runs = sorted((e["ts"], e["ts"] + e["dur"]) for e in events if e.get("name") == "model_run")
    per_run: list[dict[tuple[str, str], float]] = [defaultdict(float) for _ in runs]
    for e in events:
        if e.get("cat") != "Node" or not e["name"].endswith("_kernel_time"):
            continue
        key = (e["name"][: -len("_kernel_time")], e["args"].get("op_name", ""))
        for r, (start, end) in enumerate(runs):
            if start <= e["ts"] <= end:
                per_run[r][key] += e["dur"] / 1e3
                break
    timed = list(zip(kinds, per_run, strict=True))[2:]
    return timed, walls


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="demo:crossreg")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=2, help="profiled frames of each kind")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--json", default=None, help="write the per-node medians here")
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}, {os.cpu_count()} CPUs")
    print(f"# {' '.join(sys.argv)}")
    timed, walls = profile(args.model, (h, w), args.frames, args.threads)

    def medians(kind: str) -> dict[tuple[str, str], float]:
        runs = [r for k, r in timed if k == kind]
        keys = set().union(*runs)
        return {key: statistics.median(r.get(key, 0.0) for r in runs) for key in keys}

    learn, frozen = medians("learn"), medians("frozen")
    branch = {k: v for k, v in learn.items() if k[1] == "If"}
    only = {k: v for k, v in learn.items() if k not in frozen and k[1] != "If"}
    shared = {k: v for k, v in learn.items() if k in frozen and k[1] != "If"}
    print(
        f"\nwall ms per frame: learn {statistics.median(walls['learn']):.1f}, "
        f"frozen {statistics.median(walls['frozen']):.1f}; "
        f"If (whole branch) {sum(branch.values()):.1f} ms; nodes only a learning frame runs: "
        f"{len(only)}, {sum(only.values()):.1f} ms; the other nodes: "
        f"{sum(shared.values()):.1f} ms learning, {sum(frozen.values()):.1f} ms frozen"
    )
    by_op: dict[str, list[float]] = defaultdict(lambda: [0.0, 0])
    for (_, op), ms in only.items():
        by_op[op][0] += ms
        by_op[op][1] += 1
    print("\n| op (learning frame only) | nodes | ms |\n|---|---:|---:|")
    for op, (ms, n) in sorted(by_op.items(), key=lambda kv: -kv[1][0]):
        print(f"| {op} | {n} | {ms:.1f} |")
    print("\n| costliest learning-only node | op | ms |\n|---|---|---:|")
    for (name, op), ms in sorted(only.items(), key=lambda kv: -kv[1])[: args.top]:
        print(f"| {name} | {op} | {ms:.1f} |")
    print("\n| costliest node of both kinds | op | ms learn | ms frozen |\n|---|---|---:|---:|")
    for (name, op), ms in sorted(shared.items(), key=lambda kv: -kv[1])[:10]:
        print(f"| {name} | {op} | {ms:.1f} | {frozen[(name, op)]:.1f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(
                {"learn_only": {f"{n}|{o}": ms for (n, o), ms in only.items()},
                 "shared": {f"{n}|{o}": ms for (n, o), ms in shared.items()},
                 "walls": walls},
                fh, indent=1,
            )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
