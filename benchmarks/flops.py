"""Multiply-adds and FLOP of an exported model's convolutions at a frame size.

Counts every `Conv` node of the ONNX graph (the network: predictor, refinement, ImportanceNet,
GuideNet ...; the filter stages are custom ops and not counted), the 1 x 1 conv heads the
export writes as MatMuls (export/matmul_heads.py; their bias column is not a multiply-add), and
a conv written over its output phases (export/phase_split.py) as the K x K conv it computes:
MAC = output elements x (input channels / group) x kernel height x kernel width, and
FLOP = 2 x MAC (one multiply and one add each; biases and activations are not counted).
Channels whose weights are all zero are not the model's arithmetic: the export pads conv
widths with them for ONNX Runtime's blocked layout (export/conv_widths.py). `macs` leaves them
out (the model's cost, e.g. against a paper's budget); `executed_macs` counts them (what the
CPU multiplies). Shapes
come from ONNX shape inference at the given size; the outputs of the `rtdenoise` custom ops
(whose function bodies loop, which shape inference cannot follow) from their `OpSpec`
shape rules.

    python benchmarks/flops.py demo:afn --size 1280x720            # total and per pixel
    python benchmarks/flops.py old.onnx demo:afn --size 1280x720 --nodes

Shape inference is quick for the feed-forward families (seconds) but did not finish within
10 minutes on demo:crossreg's online-learning graph (its backward pass and Adam step).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper, shape_inference

from rtdenoise.export.matmul_heads import BIAS_ROW_DOC
from rtdenoise.export.phase_split import PHASE_SPLIT_DOC
from rtdenoise.ops import DOMAIN, get_spec


@dataclass(frozen=True)
class ConvCost:
    """One Conv node: its output name, weight shape, output shape and multiply-adds (the
    model's, without all-zero channels, and as executed)."""

    name: str
    weight: tuple[int, ...]
    output: tuple[int, ...]
    macs: int
    executed_macs: int


def _live_fraction(weight: np.ndarray | None, group: int) -> float:
    """The share of a conv's multiply-adds that involve no all-zero output or input channel."""
    if weight is None or group != 1:
        return 1.0
    c_out, c_in = weight.shape[:2]
    flat = weight.reshape(c_out, c_in, -1)
    live_out = int(np.any(flat != 0, axis=(1, 2)).sum())
    live_in = int(np.any(flat != 0, axis=(0, 2)).sum())
    return (live_out * live_in) / (c_out * c_in)


def _shape(value: onnx.ValueInfoProto) -> tuple[int, ...] | None:
    """A fully known shape, else None."""
    dims = value.type.tensor_type.shape.dim
    if not value.type.tensor_type.HasField("shape") or any(
        not d.HasField("dim_value") for d in dims
    ):
        return None
    return tuple(d.dim_value for d in dims)


def _fixed_size(model: onnx.ModelProto, height: int, width: int) -> onnx.ModelProto:
    """A copy whose image inputs (rank 4: buffers and state) are height x width, without the
    exporter's symbolic value_info."""
    model = onnx.ModelProto.FromString(model.SerializeToString())
    for value in model.graph.input:
        dims = value.type.tensor_type.shape.dim
        if len(dims) == 4:
            for dim, size in zip(dims[2:], (height, width), strict=True):
                dim.Clear()
                dim.dim_value = size
    del model.graph.value_info[:]
    return model


def infer_shapes(model: onnx.ModelProto, height: int, width: int) -> dict[str, tuple[int, ...]]:
    """Every tensor's shape at height x width: ONNX inference, with the custom ops' outputs from
    their OpSpec shape rules, repeated until nothing new is known."""
    model = _fixed_size(model, height, width)
    initializers = {t.name: tuple(t.dims) for t in model.graph.initializer}
    while True:
        model = shape_inference.infer_shapes(model, data_prop=True)
        shapes = dict(initializers)
        for value in (*model.graph.input, *model.graph.value_info, *model.graph.output):
            shape = _shape(value)
            if shape is not None:
                shapes[value.name] = shape
        added = False
        for node in model.graph.node:
            if node.domain != DOMAIN or all(o in shapes for o in node.output):
                continue
            if not all(i in shapes for i in node.input if i):
                continue
            attrs = {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}
            outs = get_spec(node.op_type).output_shapes([shapes[i] for i in node.input], attrs)
            for name, shape in zip(node.output, outs, strict=True):
                model.graph.value_info.append(
                    onnx.helper.make_tensor_value_info(name, onnx.TensorProto.FLOAT, shape)
                )
                added = True
        if not added:
            return shapes


def conv_costs(model: onnx.ModelProto | str | Path, height: int, width: int) -> list[ConvCost]:
    """The multiply-adds of every Conv node at height x width (ValueError if a shape is
    unknown)."""
    if not isinstance(model, onnx.ModelProto):
        model = onnx.load(str(model))
    shapes = infer_shapes(model, height, width)
    weights = {t.name: t for t in model.graph.initializer}
    costs = []
    for node in model.graph.node:
        if node.op_type == "MatMul" and node.doc_string == BIAS_ROW_DOC:
            costs.append(_head_cost(node, shapes, weights))
            continue
        if node.op_type != "Conv" or node.domain not in ("", "ai.onnx"):
            continue
        out, weight = shapes.get(node.output[0]), shapes.get(node.input[1])
        if out is None or weight is None:
            raise ValueError(f"Conv {node.output[0]}: shape unknown at {width}x{height}")
        n_out = 1
        for d in out:
            n_out *= d
        per_output = 1
        for d in weight[1:]:  # (C_out, C_in / group, kh, kw): one output needs C_in/g*kh*kw
            per_output *= d
        group = next((int(a.i) for a in node.attribute if a.name == "group"), 1)
        init = weights.get(node.input[1])
        live = _live_fraction(None if init is None else numpy_helper.to_array(init), group)
        if node.doc_string == PHASE_SPLIT_DOC:  # K x K of its (K + 1) x (K + 1) taps are live
            k = weight[-1] - 1
            live *= k * k / (weight[-1] * weight[-2])
        executed = n_out * per_output
        costs.append(ConvCost(node.output[0], weight, out, round(executed * live), executed))
    return costs


def _head_cost(node: onnx.NodeProto, shapes: dict, weights: dict) -> ConvCost:
    """A 1 x 1 conv head as the export writes it (export/matmul_heads.py): MatMul((T, C + 1)
    weights, (N, C + 1, H*W) input whose last row is ones); the bias column is not counted."""
    out, weight = shapes.get(node.output[0]), shapes.get(node.input[0])
    if out is None or weight is None:
        raise ValueError(f"MatMul {node.output[0]}: shape unknown")
    n_out = int(np.prod(out))
    init = weights.get(node.input[0])
    w = None if init is None else numpy_helper.to_array(init)[:, :-1, None, None]
    executed = n_out * weight[1]
    return ConvCost(
        node.output[0], weight, out, round(n_out * (weight[1] - 1) * _live_fraction(w, 1)), executed
    )


def conv_gflop(model: onnx.ModelProto | str | Path, height: int, width: int) -> float:
    """GFLOP (2 x multiply-adds) of the Conv nodes per height x width frame."""
    return 2 * sum(c.macs for c in conv_costs(model, height, width)) / 1e9


def _resolve(model: str) -> Path:
    if model.startswith("demo:"):
        from rtdenoise.shipped import MODELS_DIR

        return MODELS_DIR / f"{model[5:]}.onnx"
    return Path(model)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("models", nargs="+", help="ONNX files or demo:<family>")
    parser.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT (default 1280x720)")
    parser.add_argument("--nodes", action="store_true", help="list every Conv node")
    parser.add_argument("--json", action="store_true", help="print JSON")
    args = parser.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    results = []
    for name in args.models:
        costs = conv_costs(_resolve(name), height, width)
        macs = sum(c.macs for c in costs)
        executed = sum(c.executed_macs for c in costs)
        r = {
            "model": name,
            "size": f"{width}x{height}",
            "convs": len(costs),
            "mac_per_pixel": macs / (width * height),
            "gflop": 2 * macs / 1e9,
            "executed_gflop": 2 * executed / 1e9,
            "nodes": [c.__dict__ for c in costs] if args.nodes else None,
        }
        results.append(r)
        if args.json:
            continue
        print(
            f"{r['model']}: {r['convs']} Conv nodes, {r['mac_per_pixel'] / 1e3:.2f} k MAC/pixel, "
            f"{r['gflop']:.2f} GFLOP per {r['size']} frame (FLOP = 2 x multiply-adds)"
            + (
                f"; {r['executed_gflop']:.2f} executed with the zero channels padded for NCHWc"
                if executed != macs
                else ""
            ),
            flush=True,
        )
        for c in r["nodes"] or []:
            padded = c["executed_macs"] != c["macs"]
            print(
                f"  {c['name']:<14} weight {c['weight']} -> {c['output']}: {c['macs'] / 1e6:.1f} M"
                + (f" ({c['executed_macs'] / 1e6:.1f} M executed)" if padded else "")
            )
    if args.json:
        json.dump(results, sys.stdout, indent=1)
        print()


if __name__ == "__main__":
    main()
