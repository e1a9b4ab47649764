"""Per-stage time of one frame, PyTorch eager vs ONNX Runtime (fast and portable), in one run.

A model whose `forward` marks its stages with `models.profiling.stage` (crossreg: regression,
reprojection, unet, filter, backward, adam) is timed in PyTorch by the wall time of each stage
(`models.profiling.timed_stages`). In ONNX Runtime the session profiler times every node,
and each node is assigned to a stage from the graph alone:

- `regression`, `filter`: the custom op node of the stage (STAGE_OF_OP);
- `backward + adam`: the nodes only the learned state needs: ancestors of the state outputs that
  `rtdenoise.online` names (parameters, moments, step) that are not ancestors of `output` or of
  any other output (the gradient and the optimiser step), and the nodes of the `If` branches
  that hold them (export/learning_branch.py; the `If` itself is not counted: its time is its
  branch's nodes');
- `unet`: the remaining nodes downstream of the graph's first Conv and upstream of the next
  custom op node (the network and its output transforms);
- `other`: the rest (reprojection, blending, loss, glue).

ONNX Runtime renames the nodes it rewrites while it optimises the graph, and its profiler
reports them by their new names: a fusion keeps the first node's name and appends
`/<Fusion>/` (`node_mm/MatmulTransposeFusion/`: the weight gradients' products), a rewrite
appends `_token_<n>`. `profiled_stage` maps such a name back to the stage of the node it
started from; a node ORT made itself (`Transpose_token_0`, NCHWc's `ReorderInput` /
`ReorderOutput`) takes the stage of the node it converts a tensor for: the next node run (the
previous one for `ReorderOutput`). Counting them all as `other` had left out a third of the
backward pass's time (demo:crossreg before its ConvWeightGrad, 720p, 2 threads: 1171 ms of its
1687; benchmarks/README.md, "crossreg's warp and weight gradients as ops").

On the portable path ORT inlines the custom ops' function bodies under generated names, so only
its total per frame is reported.

Medians over `repeats` frames after one warm-up frame, state fed back as in production.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import onnx
import onnxruntime as ort
import torch

from rtdenoise.models.base import DenoiserModel
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.models.profiling import timed_stages
from rtdenoise.runtime import bridge
from rtdenoise.runtime.contract import RESET, contract_from_session
from rtdenoise.runtime.session import ALLOW_SPINNING, kernel_thread_count
from rtdenoise.runtime.static_check import custom_op_types

from .learning_branch import all_nodes, subgraphs
from .validate import synthetic_frames

STAGES = ("regression", "unet", "filter", "backward + adam", "other")
STAGE_OF_OP = {
    "CrossRegression": "regression",
    "CrossBilateralFilter": "filter",
    "SvgfReproject": "other",  # the reprojection: PyTorch's `other` as well
    "ConvWeightGrad": "backward + adam",
}
TORCH_STAGE = {  # torch.profiler range -> reported stage
    "regression": "regression",
    "unet": "unet",
    "filter": "filter",
    "backward": "backward + adam",
    "adam": "backward + adam",
}


def _ancestors(graph: onnx.GraphProto, names: set[str]) -> set[int]:
    """Indices of the nodes that the tensors `names` depend on."""
    producer = {out: i for i, node in enumerate(graph.node) for out in node.output}
    seen: set[int] = set()
    todo = [producer[n] for n in names if n in producer]
    while todo:
        i = todo.pop()
        if i in seen:
            continue
        seen.add(i)
        todo.extend(producer[x] for x in graph.node[i].input if x in producer)
    return seen


def node_stages(model: onnx.ModelProto, online: dict | None) -> dict[str, str | None]:
    """{node name: stage} for every node of the graph and its subgraphs (see the module
    docstring); None for a node that holds subgraphs (not counted)."""
    graph = model.graph
    outputs = [o.name for o in graph.output]
    learned = {
        f"state_next.{n}"
        for n in [(online or {}).get("parameters"), (online or {}).get("step")]
        + list((online or {}).get("moments", []))
        if n
    }
    backward = _ancestors(graph, learned) - _ancestors(graph, set(outputs) - learned)
    order = list(range(len(graph.node)))
    first_conv = next((i for i in order if graph.node[i].op_type == "Conv"), None)
    unet: set[int] = set()
    if first_conv is not None:
        custom = [i for i in order if i > first_conv and graph.node[i].domain == "rtdenoise"]
        if custom:
            up = _ancestors(graph, set(graph.node[custom[0]].input))
            down, made = {first_conv}, set(graph.node[first_conv].output)
            for i in order[first_conv + 1 :]:  # topological order: one forward pass
                if any(x in made for x in graph.node[i].input):
                    down.add(i)
                    made.update(graph.node[i].output)
            unet = (up & down) - backward
    stages: dict[str, str | None] = {}
    for i, node in enumerate(graph.node):
        inner = [sub for g in subgraphs(node) for sub in all_nodes(g)]
        if inner:
            stages[node.name] = None
            for sub in inner:
                if sub.domain == "rtdenoise":
                    stages[sub.name] = STAGE_OF_OP.get(sub.op_type, sub.op_type)
                else:
                    stages[sub.name] = "backward + adam" if i in backward else "other"
        elif node.domain == "rtdenoise":
            stages[node.name] = STAGE_OF_OP.get(node.op_type, node.op_type)
        elif i in backward:
            stages[node.name] = "backward + adam"
        elif i in unet:
            stages[node.name] = "unet"
        else:
            stages[node.name] = "other"
    return stages


# what a node ORT made itself is counted as (`profiled_stage`, `node_ms_per_run`)
NEXT, PREVIOUS = "<next node's>", "<previous node's>"
_RENAMED = re.compile(r"/|_token_")  # where ORT's suffixes for a rewritten node begin


def profiled_stage(name: str, stages: dict[str, str | None]) -> str | None:
    """The stage of a node as ORT's profiler names it (module docstring): its own name's, or
    that of the longest original name it extends by ORT's suffixes; NEXT or PREVIOUS for a
    node ORT made; `other` for a named node of no stage."""
    if name in stages:
        return stages[name]
    for cut in sorted((m.start() for m in _RENAMED.finditer(name)), reverse=True):
        if name[:cut] in stages:
            return stages[name[:cut]]
    return PREVIOUS if name.startswith("ReorderOutput") else NEXT


def node_ms_per_run(
    profile: str, bucket: Callable[[str, str], str | None]
) -> list[dict[str, float]]:
    """Per session run of an ONNX Runtime profile file (in order): ms of its nodes' kernels
    summed per `bucket(node name, op type)` (None: not counted; NEXT / PREVIOUS: the key of the
    next / previous counted node of the run, in the order ORT ran them)."""
    with open(profile) as fh:
        events = json.load(fh)
    runs = sorted((e["ts"], e["ts"] + e["dur"]) for e in events if e.get("name") == "model_run")
    timed: list[list[tuple[float, str | None, float]]] = [[] for _ in runs]
    for e in events:
        if e.get("cat") != "Node" or not e["name"].endswith("_kernel_time"):
            continue
        key = bucket(e["name"][: -len("_kernel_time")], e["args"].get("op_name", ""))
        for r, (start, end) in enumerate(runs):
            if start <= e["ts"] <= end:
                timed[r].append((e["ts"], key, e["dur"] / 1e3))
                break
    per_run: list[dict[str, float]] = [defaultdict(float) for _ in runs]
    for run, nodes in zip(per_run, timed, strict=True):
        keys = [key for _, key, _ in sorted(nodes, key=lambda t: t[0])]
        durations = [ms for _, _, ms in sorted(nodes, key=lambda t: t[0])]
        for direction in (NEXT, PREVIOUS):  # a run of ORT-made nodes inherits as one
            order = range(len(keys)) if direction == PREVIOUS else range(len(keys) - 1, -1, -1)
            last = None
            for i in order:
                if keys[i] in (NEXT, PREVIOUS):
                    if keys[i] == direction and last is not None:
                        keys[i] = last
                elif keys[i] is not None:  # not an uncounted If
                    last = keys[i]
        for key, ms in zip(keys, durations, strict=True):
            if key is not None:
                run[key if key not in (NEXT, PREVIOUS) else "other"] += ms
    return per_run


@dataclass
class ProfiledRun:
    """A profiled ONNX Runtime session of an exported model, its node -> stage map, its state
    carried from frame to frame and its frame wall times (ms)."""

    session: ort.InferenceSession
    chosen: str | None  # the fast-kernel bridge registered, None on the portable path
    stage_of: dict[str, str | None]
    contract: object
    state: dict[str, np.ndarray] = field(default_factory=dict)
    walls: list[float] = field(default_factory=list)

    def frame(self, frame: dict, first: bool, threads: int | None) -> None:
        """Run one frame (reset and zero state on the first), feed its state back, time it."""
        contract = self.contract
        h, w = frame[contract.buffer_names[0]].shape[-2:]
        if first:
            self.state = {s.name: np.zeros(s.shape(h, w), np.float32) for s in contract.state}
        feed = {name: frame[name][None] for name in contract.buffer_names}
        feed[RESET] = np.array(1.0 if first else 0.0, np.float32)
        feed.update({s.input_name: self.state[s.name] for s in contract.state})
        team = kernel_thread_count((h, w), threads)
        t0 = time.perf_counter()
        with bridge.kernel_threads(self.chosen, team) if self.chosen else contextlib.nullcontext():
            outs = self.session.run(None, feed)
        self.walls.append((time.perf_counter() - t0) * 1e3)
        named = dict(zip([o.name for o in self.session.get_outputs()], outs, strict=True))
        self.state = {s.name: named[s.output_name] for s in contract.state}

    def stage_ms(self) -> list[dict[str, float]]:
        """Ends the profile: ms per stage of every frame run so far."""
        return node_ms_per_run(
            self.session.end_profiling(), lambda node, _op: profiled_stage(node, self.stage_of)
        )


def profiled_run(
    onnx_bytes: bytes, fast: bool, threads: int | None, prefix: str = "ort"
) -> ProfiledRun:
    """A ProfiledRun of an exported model: the fast path as Denoiser runs it (the bridge it
    picks for the model's ops, idle ORT workers sleeping while a kernel runs), or portable."""
    proto = onnx.load_from_string(onnx_bytes)
    for i, node in enumerate(all_nodes(proto.graph)):  # the profiler reports nodes by name
        node.name = node.name or f"node_{i}"
    so = ort.SessionOptions()
    if threads:
        so.intra_op_num_threads = threads
    chosen = None
    if fast:
        chosen = bridge.register_fast_kernels(so, None, custom_op_types(onnx_bytes))
        so.add_session_config_entry(ALLOW_SPINNING, "0")
    so.enable_profiling = True
    so.profile_file_prefix = os.path.join(tempfile.mkdtemp(), prefix)
    session = ort.InferenceSession(
        proto.SerializeToString(), so, providers=["CPUExecutionProvider"]
    )
    contract = contract_from_session(session)
    return ProfiledRun(session, chosen, node_stages(proto, contract.online), contract)


def _ort_times(onnx_bytes: bytes, frames, fast: bool, threads: int | None) -> tuple[dict, float]:
    """(median ms per stage, median ms per frame) of ONNX Runtime over frames[1:]."""
    profiled = profiled_run(onnx_bytes, fast, threads)
    for k, frame in enumerate(frames):
        profiled.frame(frame, k == 0, threads)
    per_run, walls = profiled.stage_ms(), profiled.walls
    timed = per_run[1:] or per_run
    return {s: float(np.median([run.get(s, 0.0) for run in timed])) for s in STAGES}, float(
        np.median(walls[1:] or walls)
    )


def _torch_times(model: DenoiserModel, frames) -> tuple[dict, float]:
    """(median ms per stage, median ms per frame) of PyTorch eager over frames[1:]."""
    loop = FrameLoop(model)
    per_frame, walls = [], []
    with torch.no_grad():
        for frame in frames:
            with timed_stages() as times:
                t0 = time.perf_counter()
                loop(frame)
                walls.append((time.perf_counter() - t0) * 1e3)
            stages: dict[str, float] = defaultdict(float)
            for name, ms in times.items():
                if name in TORCH_STAGE:
                    stages[TORCH_STAGE[name]] += ms
            per_frame.append(stages)
    timed, wall = per_frame[1:] or per_frame, float(np.median(walls[1:] or walls))
    out = {s: float(np.median([f.get(s, 0.0) for f in timed])) for s in STAGES[:-1]}
    rest = [w - sum(f.values()) for w, f in zip(walls[1:] or walls, timed, strict=True)]
    out["other"] = float(np.median(rest))
    return out, wall


def benchmark_stages(
    model: DenoiserModel,
    onnx_bytes: bytes,
    size: tuple[int, int] = (720, 1280),
    repeats: int = 3,
    threads: int | None = None,
    progress: Callable[[str], None] | None = None,
    portable: bool = True,
) -> dict:
    """{path: {"stages": {stage: ms}, "total": ms}} for torch, ort_fast and (with `portable`)
    ort_portable."""
    say = progress or (lambda _msg: None)
    if threads:
        torch.set_num_threads(threads)
    frames = synthetic_frames(model.inputs, repeats + 1, *size)
    result = {}
    paths = {
        "torch": lambda: _torch_times(model.eval(), frames),
        "ort_fast": lambda: _ort_times(onnx_bytes, frames, True, threads),
        "ort_portable": lambda: _ort_times(onnx_bytes, frames, False, threads),
    }
    if not portable:
        del paths["ort_portable"]
    for path, run in paths.items():
        say(path)
        stages, total = run()
        # ORT inlines the portable function bodies under generated node names (and reports
        # their Loop bodies' nodes as well): only its total is meaningful
        result[path] = {"stages": stages if path != "ort_portable" else {}, "total": total}
    return result
