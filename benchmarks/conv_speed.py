"""Each conv of an exported model, alone, in ONNX Runtime and in PyTorch eager, interleaved.

For every `Conv` node of the graph (shapes at the given size from `flops.py`'s inference):
a one-node ORT session (CPU provider, ORT_ENABLE_ALL: ORT picks its blocked NCHWc kernel or
plain NCHW itself, reorders at the session's edges included) and `torch.nn.functional.conv2d`
on NCHW tensors (what a PyTorch model runs by default) and on channels-last tensors; random
inputs of the node's shape, the node's own weights; threads as given (both libraries).
Median ms per call over `--repeats` rounds (A B C A B C ..., after a warm-up call), and GFLOP/s
of the executed multiply-adds. Shows where the networks' time goes in each library. Both run
as `denoise-bench compare` runs them: idle OpenMP workers sleeping (OMP_WAIT_POLICY=PASSIVE)
and large blocks served from the reused malloc heap (`tune_allocator`); without it each
torch call page-faults its fresh output (at 720p that doubled torch's time per conv on a
2-core AVX-512 VM, where a conv inside the eager model ran at ORT's speed, not half of it).

    python benchmarks/conv_speed.py demo:wskp --size 1280x720 --repeats 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from functools import partial
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as the CLIs set it, before torch loads

import numpy as np  # noqa: E402
import onnx  # noqa: E402
import onnxruntime as ort  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from rtdenoise.runtime.memory import tune_allocator  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import flops  # noqa: E402


def conv_model(node: onnx.NodeProto, inits: dict, shape: tuple[int, ...]) -> bytes:
    """A one-node model: the conv with its attributes and weights, input of `shape`."""
    params = [inits[i] for i in node.input[1:] if i]
    conv = helper.make_node("Conv", ["x", *node.input[1:]], ["y"])
    conv.attribute.extend(node.attribute)
    graph = helper.make_graph(
        [conv],
        "conv",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, list(shape))],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        params,
    )
    opset = [helper.make_opsetid("", 18)]
    return helper.make_model(graph, opset_imports=opset, ir_version=10).SerializeToString()


def torch_args(node: onnx.NodeProto, inits: dict) -> tuple[tuple[int, ...], dict]:
    """(F.pad widths, conv2d keywords) of an ONNX Conv: symmetric pads go to conv2d, others
    (export/phase_split.py's stride-2 convs) to an explicit zero pad first."""
    attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
    top, left, bottom, right = attrs.get("pads", [0, 0, 0, 0])
    symmetric = (top, left) == (bottom, right)
    explicit = (0, 0, 0, 0) if symmetric else (left, right, top, bottom)
    weight = torch.from_numpy(numpy_helper.to_array(inits[node.input[1]]).copy())
    bias = node.input[2] if len(node.input) > 2 and node.input[2] else None
    return explicit, {
        "weight": weight,
        "bias": None
        if bias is None
        else torch.from_numpy(numpy_helper.to_array(inits[bias]).copy()),
        "stride": tuple(attrs.get("strides", [1, 1])),
        "padding": (top, left) if symmetric else (0, 0),
        "dilation": tuple(attrs.get("dilations", [1, 1])),
        "groups": attrs.get("group", 1),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("model", help="ONNX file or demo:<family>")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="0: each library's default")
    args = ap.parse_args(argv)
    tune_allocator()
    width, height = (int(v) for v in args.size.split("x"))
    path = flops._resolve(args.model)
    model = onnx.load(str(path))
    inits = {i.name: i for i in model.graph.initializer}
    shapes = flops.infer_shapes(model, height, width)
    costs = {c.name: c for c in flops.conv_costs(model, height, width)}
    if args.threads:
        torch.set_num_threads(args.threads)
    so = ort.SessionOptions()
    so.intra_op_num_threads = args.threads
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    rng = np.random.default_rng(0)
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC; {' '.join(sys.argv)}")
    print("| conv | weight | output | ORT ms | torch NCHW ms | torch channels-last ms |")
    print("|---|---|---|---:|---:|---:|")
    totals = np.zeros(3)
    for node in model.graph.node:
        if node.op_type != "Conv" or node.output[0] not in costs:
            continue
        shape = shapes[node.input[0]]
        x = rng.standard_normal(shape, dtype=np.float32)
        sess = ort.InferenceSession(conv_model(node, inits, shape), so)
        pad, targs = torch_args(node, inits)
        xt = F.pad(torch.from_numpy(x), pad)
        xl = xt.contiguous(memory_format=torch.channels_last)
        targs_l = dict(targs, weight=targs["weight"].contiguous(memory_format=torch.channels_last))
        calls = (
            partial(sess.run, None, {"x": x}),
            partial(F.conv2d, xt, **targs),
            partial(F.conv2d, xl, **targs_l),
        )
        times: list[list[float]] = [[] for _ in calls]
        with torch.inference_mode():
            for r in range(args.repeats + 1):
                for t, call in zip(times, calls, strict=True):
                    t0 = time.perf_counter()
                    call()
                    if r:
                        t.append((time.perf_counter() - t0) * 1e3)
        ms = np.array([statistics.median(t) for t in times])
        totals += ms
        gflop = 2 * costs[node.output[0]].executed_macs / 1e9
        cells = " | ".join(f"{m:.1f} ({gflop / m * 1e3:.0f} GFLOP/s)" for m in ms)
        c = costs[node.output[0]]
        print(f"| {node.output[0]} | {c.weight} | {c.output} | {cells} |", flush=True)
    print(f"| all | | | {totals[0]:.1f} | {totals[1]:.1f} | {totals[2]:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
