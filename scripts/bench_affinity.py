"""AffinityFilter at 720p (13 x 13 taps, d = 8 features): the fast kernel, ORT with it, ORT
portable and torch eager side by side (`denoise-bench op`'s `bench_op`), and the achieved
GFLOP/s against what ONNX Runtime's own convolutions reach on this machine, measured in the
same run (a 6-layer 5 x 5 width-14 conv net at 720p, timed alternately with the fast kernel so
that a change of load on a shared machine hits both).

    python scripts/bench_affinity.py [--threads 2] [--repeats 5] [--dilation 1]

FLOPs of the filter: per pixel and per non-centre tap inside the image, the squared feature
distance (3 d), the bandwidth product (1), the exponential (counted as 1), the weight sum (1)
and the weighted colour (2 C): 3 d + 3 + 2 C = 33 for d = 8, C = 3 (the useful arithmetic; the
fast kernel's polynomial exp costs about 12 instructions more).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from rtdenoise.export.op_bench import bench_op
from rtdenoise.ops import get_spec

H, W = 720, 1280


def affinity_flops(h: int, w: int, k: int, d: int, c: int, dilation: int) -> float:
    """Useful FLOPs of one AffinityFilter call (taps outside the image not counted)."""
    r = k // 2
    taps = 0
    for i in range(k):
        for j in range(k):
            if i == r and j == r:
                continue
            dy, dx = abs(i - r) * dilation, abs(j - r) * dilation
            taps += max(0, h - dy) * max(0, w - dx)
    return float(taps * (3 * d + 3 + 2 * c))


def conv_net(layers: int = 6, width: int = 14, k: int = 5) -> tuple[bytes, float]:
    """A plain conv net (ReLU between layers) and its FLOPs per 720p frame."""
    rng = np.random.default_rng(0)
    nodes, inits = [], []
    x = "x"
    for i in range(layers):
        wname, bname, y = f"w{i}", f"b{i}", f"y{i}"
        weight = (rng.standard_normal((width, width, k, k)) * 0.05).astype(np.float32)
        inits += [numpy_helper.from_array(weight, wname), numpy_helper.from_array(
            np.zeros(width, np.float32), bname)]  # fmt: skip
        nodes.append(helper.make_node("Conv", [x, wname, bname], [y], pads=[k // 2] * 4))
        if i < layers - 1:
            nodes.append(helper.make_node("Relu", [y], [f"r{i}"]))
            y = f"r{i}"
        x = y
    graph = helper.make_graph(
        nodes,
        "convnet",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, width, H, W])],
        [helper.make_tensor_value_info(x, TensorProto.FLOAT, [1, width, H, W])],
        inits,
    )
    model = helper.make_model(graph, ir_version=10, opset_imports=[helper.make_opsetid("", 18)])
    onnx.checker.check_model(model)
    return model.SerializeToString(), 2.0 * layers * width * width * k * k * H * W


def interleaved(threads: int, repeats: int, dilation: int) -> tuple[float, float, float]:
    """(conv ms, conv GFLOP/s, fast kernel ms): medians of ORT's 720p conv net and the fast
    AffinityFilter kernel timed alternately, so that a change of machine load hits both."""
    import numba

    from rtdenoise.runtime.kernels import KERNELS

    data, flops = conv_net()
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    sess = ort.InferenceSession(data, so, providers=["CPUExecutionProvider"])
    x = np.random.default_rng(1).random((1, 14, H, W), dtype=np.float32)
    attrs = {"dilation": dilation}
    inputs = get_spec("AffinityFilter").example_inputs(
        (1, 3, H, W), attrs, np.random.default_rng(0)
    )
    numba.set_num_threads(threads)
    kernel = KERNELS["AffinityFilter"]
    sess.run(None, {"x": x})
    kernel(*inputs, **attrs)
    conv, fast = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sess.run(None, {"x": x})
        t1 = time.perf_counter()
        kernel(*inputs, **attrs)
        conv.append(t1 - t0)
        fast.append(time.perf_counter() - t1)
    conv_ms = float(np.median(conv) * 1e3)
    return conv_ms, flops / (conv_ms * 1e-3) / 1e9, float(np.median(fast) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dilation", type=int, default=1)
    args = parser.parse_args()

    conv_ms, peak, fast_ms = interleaved(args.threads, args.repeats, args.dilation)
    result = bench_op(
        "AffinityFilter",
        (1, 3, H, W),
        repeats=args.repeats,
        attrs={"dilation": args.dilation},
        threads=args.threads,
    )
    inputs = get_spec("AffinityFilter").example_inputs(
        (1, 3, H, W), result["attrs"], np.random.default_rng(0)
    )
    k, d = int(inputs[4]), inputs[1].shape[1]
    flops = affinity_flops(H, W, k, d, 3, args.dilation)
    print(
        f"ORT conv (6 x 5x5 width 14, 720p): {conv_ms:.0f} ms median = {peak:.1f} GFLOP/s "
        f"(attainable, {args.threads} threads)"
    )
    print(
        f"AffinityFilter 1x3x{H}x{W}, {k}x{k} taps, d = {d}, dilation {args.dilation}: "
        f"{flops / 1e9:.2f} GFLOP; attainable {flops / peak / 1e6:.0f} ms"
    )
    print(
        f"interleaved with the conv net: fast kernel {fast_ms:.0f} ms = "
        f"{flops / fast_ms / 1e6:.1f} GFLOP/s = {fast_ms / (flops / peak / 1e6):.2f} x attainable"
    )
    print("the four forms side by side (denoise-bench op AffinityFilter):")
    print(f"{'form':<14}{'median ms':>10}{'GFLOP/s':>10}{'x attainable':>14}{'max |diff|':>12}")
    for form, ms in result["ms"].items():
        rate = flops / (ms * 1e-3) / 1e9
        diff = result["max_abs_diff"].get(form, 0.0)
        print(f"{form:<14}{ms:>10.0f}{rate:>10.1f}{ms / (flops / peak / 1e6):>14.1f}{diff:>12.2e}")


if __name__ == "__main__":
    main()
