"""Rewrite an exported model so that no Conv reads a channel Concat: tried, not kept.

    python benchmarks/concat_split.py rtdenoise/assets/models/afn.onnx -o /tmp/afn_split.onnx \
        --conv node_conv2d_9 --conv node_conv2d_11 --conv node_conv2d_13 --conv node_conv2d_15
    denoise-bench compare rtdenoise/assets/models/afn.onnx /tmp/afn_split.onnx --oidn none \
        --size 320x240 --size 1280x720 --repeats 9

Conv(Concat(a, b), W) = Conv(a, W[:, :Ca]) + Conv(b, W[:, Ca:]): the U-Net's skip joins without
writing the concatenated tensor. ONNX Runtime's NCHWc transformer fuses such an Add into the
second conv (its Sum input) only if it can prove both conv outputs have the same shape, which
it cannot for a Resize's output, so the sum's shape is stated as the original conv output's
(value_info). Outputs match the original within float rounding (1e-6). The result is in
benchmarks/README.md (no gain: the fused Sum costs what the Concat did).
"""

from __future__ import annotations

import argparse

import numpy as np
import onnx
from onnx import helper, numpy_helper, shape_inference

from rtdenoise.export.conv_widths import Graph


def split_concat_convs(
    model: onnx.ModelProto, only: set[str] | None = None
) -> tuple[onnx.ModelProto, list[str]]:
    """The model with every plain Conv (group 1, weights of its own) whose input is a channel
    Concat (used by it alone) replaced by one Conv per Concat input, summed (only the convs
    named in `only`, if given); and the names of the convs split."""
    model = shape_inference.infer_shapes(model)
    graph = model.graph
    infos = {v.name: v for v in graph.value_info}
    known = Graph(model)  # initializers, their uses, inferred channel counts
    producer = {o: n for n in graph.node for o in n.output}
    nodes, split, dropped = [], [], set()
    for node in graph.node:
        cat = producer.get(node.input[0]) if node.op_type == "Conv" else None
        axis = {a.name: helper.get_attribute_value(a) for a in cat.attribute} if cat else {}
        if cat is None or cat.op_type != "Concat" or axis.get("axis") != 1:
            nodes.append(node)
            continue
        parts = list(cat.input)
        if (
            not known.plain_conv(node)
            or known.uses[node.input[0]] != 1
            or not all(known.channels.get(p) for p in parts)
            or (only is not None and node.name not in only)
        ):
            nodes.append(node)
            continue
        weight = numpy_helper.to_array(known.inits[node.input[1]])
        attrs = {a.name: helper.get_attribute_value(a) for a in node.attribute}
        outputs, start = [], 0
        for k, part in enumerate(parts):
            width = known.channels[part]
            w_name = f"{node.name}_w{k}"
            part_weight = np.ascontiguousarray(weight[:, start : start + width])
            graph.initializer.append(numpy_helper.from_array(part_weight, w_name))
            start += width
            inputs = [part, w_name] + (list(node.input[2:3]) if k == 0 else [])
            outputs.append(f"{node.name}_part{k}")
            conv = helper.make_node("Conv", inputs, [outputs[-1]], f"{node.name}_c{k}", **attrs)
            nodes.append(conv)
        total = outputs[0]
        for k, part_out in enumerate(outputs[1:], 1):
            out = node.output[0] if k == len(outputs) - 1 else f"{node.name}_sum{k}"
            nodes.append(helper.make_node("Add", [total, part_out], [out], f"{node.name}_add{k}"))
            total = out
        for name in outputs + [f"{node.name}_sum{k}" for k in range(1, len(outputs) - 1)]:
            info = onnx.ValueInfoProto()
            info.CopyFrom(infos[node.output[0]])
            info.name = name
            graph.value_info.append(info)
        dropped.add(cat.name)
        split.append(node.name)
    del graph.node[:]
    graph.node.extend(n for n in nodes if n.name not in dropped)
    return model, split


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="exported .onnx file")
    parser.add_argument("-o", "--output", required=True)
    parser.add_argument("--conv", action="append", help="split only this conv (repeatable)")
    args = parser.parse_args()
    model, split = split_concat_convs(onnx.load(args.model), set(args.conv) if args.conv else None)
    onnx.checker.check_model(model)
    onnx.save(model, args.output)
    print(f"split {len(split)} convs: {', '.join(split)} -> {args.output}")


if __name__ == "__main__":
    main()
