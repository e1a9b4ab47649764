"""ONNX form of the custom ops: schemas, exporter translations, model-local function bodies.

Adding an op: a new module with a `SPEC` (see base.OpSpec), and one line in `OPS`.

Export recipe (what `to_onnx` does):
    torch.onnx.export(module, args, dynamo=True, opset_version=OPSET,
                      dynamic_shapes=..., custom_translation_table=custom_translation_table())
    model = attach_functions(program.model_proto)   # + rtdenoise opset import, IR 10
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import onnx
from onnx import TensorProto, helper

from . import adaptive_fusion, kernel_apply, kernel_fusion, weight_sharing_filter
from .base import DOMAIN, DOMAIN_VERSION, IR_VERSION, OPSET, OpSpec

OPS: list[OpSpec] = [
    kernel_apply.SPEC,
    adaptive_fusion.SPEC,
    weight_sharing_filter.SPEC,
    kernel_fusion.SPEC,
]
SPECS: dict[str, OpSpec] = {s.name: s for s in OPS}

__all__ = [
    "DOMAIN",
    "DOMAIN_VERSION",
    "IR_VERSION",
    "OPS",
    "OPSET",
    "SPECS",
    "OpSpec",
    "attach_functions",
    "custom_translation_table",
    "export_options",
    "exporting",
    "function_protos",
    "single_op_model",
    "to_onnx",
    "used_ops",
]


def custom_translation_table() -> dict:
    """{torch.ops.rtdenoise.<op>.default: onnxscript translation} for torch.onnx.export."""
    return {spec.torch_op(): spec.translation for spec in OPS}


def exporting(enabled: bool = True):
    """Context manager forcing the custom-op form of the torch ops (models.ops.exporting).

    Not required under torch.onnx.export(dynamo=True), where torch.compiler.is_exporting()
    already switches the ops; useful for other tracers.
    """
    from rtdenoise.models.ops import exporting as _exporting

    return _exporting(enabled)


def export_options() -> dict[str, Any]:
    """Keyword arguments for torch.onnx.export that emit the rtdenoise custom nodes."""
    return {
        "dynamo": True,
        "opset_version": OPSET,
        "custom_translation_table": custom_translation_table(),
    }


def _model_opset(model: onnx.ModelProto) -> int:
    for imp in model.opset_import:
        if imp.domain in ("", "ai.onnx"):
            return int(imp.version)
    return OPSET


def _graph_nodes(graph: onnx.GraphProto) -> Iterable[onnx.NodeProto]:
    for node in graph.node:
        yield node
        for attr in node.attribute:
            if attr.type == onnx.AttributeProto.GRAPH:
                yield from _graph_nodes(attr.g)
            elif attr.type == onnx.AttributeProto.GRAPHS:
                for g in attr.graphs:
                    yield from _graph_nodes(g)


def used_ops(model: onnx.ModelProto) -> list[str]:
    """Names of the rtdenoise ops the graph (including subgraphs and functions) uses."""
    names: set[str] = set()
    nodes = list(_graph_nodes(model.graph))
    for f in model.functions:
        if f.domain != DOMAIN:
            nodes.extend(f.node)
    for node in nodes:
        if node.domain == DOMAIN:
            if node.op_type not in SPECS:
                raise ValueError(f"unknown custom op {DOMAIN}.{node.op_type}")
            names.add(node.op_type)
    return sorted(names)


def function_protos(used_op_names: Sequence[str], opset: int = OPSET) -> list[onnx.FunctionProto]:
    """Model-local FunctionProtos (bodies in ai.onnx opset `opset`) for the named ops."""
    return [SPECS[name].build_function(opset) for name in sorted(set(used_op_names))]


def attach_functions(model: onnx.ModelProto) -> onnx.ModelProto:
    """Add the FunctionProto of every rtdenoise op the graph uses (in place; returns `model`).

    Also adds the `rtdenoise` opset import (version 1). Existing rtdenoise functions are
    replaced, so calling it twice is harmless.
    """
    names = used_ops(model)
    keep = [f for f in model.functions if not (f.domain == DOMAIN and f.name in SPECS)]
    del model.functions[:]
    model.functions.extend(keep)
    model.functions.extend(function_protos(names, _model_opset(model)))
    if names and not any(i.domain == DOMAIN for i in model.opset_import):
        model.opset_import.append(helper.make_opsetid(DOMAIN, DOMAIN_VERSION))
    return model


def to_onnx(module, args: tuple, dynamic_shapes=None, **kwargs) -> onnx.ModelProto:
    """Export `module` with the custom nodes and attach their function bodies.

    Extra keyword arguments go to torch.onnx.export (e.g. input_names, output_names).
    """
    import torch

    options = export_options() | kwargs
    program = torch.onnx.export(module, args, dynamic_shapes=dynamic_shapes, **options)
    return attach_functions(program.model_proto)


def single_op_model(
    op_name: str,
    input_shapes: Sequence[Sequence[int | str | None]],
    attrs: dict[str, int] | None = None,
    with_function: bool = True,
    output_shapes: Sequence[Sequence[int | str | None]] | None = None,
) -> onnx.ModelProto:
    """A one-node model `rtdenoise.<op_name>` (IR 10, opset 18) for tests and benchmarks.

    input_shapes: one shape per op input, dims as ints or names (dynamic); attrs: the int
    attributes (all required). with_function=False leaves the FunctionProto out, so the model
    only runs when the fast kernels are registered. output_shapes defaults to the op's
    `OpSpec.output_shape`, else to the first input's shape for every output.
    """
    spec = SPECS[op_name]
    attrs = dict(attrs or {})
    if set(attrs) != set(spec.int_attrs):
        raise ValueError(f"{op_name} needs attributes {spec.int_attrs}, got {sorted(attrs)}")
    if len(input_shapes) != len(spec.inputs):
        raise ValueError(f"{op_name} has {len(spec.inputs)} inputs, got {len(input_shapes)} shapes")
    if output_shapes is None and spec.output_shape is not None:
        output_shapes = spec.output_shape([list(x) for x in input_shapes], attrs)
    out_shapes = output_shapes or [input_shapes[0]] * len(spec.outputs)
    node = helper.make_node(op_name, list(spec.inputs), list(spec.outputs), domain=DOMAIN, **attrs)
    graph = helper.make_graph(
        [node],
        f"single_{op_name}",
        [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape))
            for name, shape in zip(spec.inputs, input_shapes, strict=True)
        ],
        [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape))
            for name, shape in zip(spec.outputs, out_shapes, strict=True)
        ],
    )
    model = helper.make_model(
        graph,
        ir_version=IR_VERSION,
        opset_imports=[helper.make_opsetid("", OPSET), helper.make_opsetid(DOMAIN, DOMAIN_VERSION)],
        producer_name="rtdenoise",
    )
    if with_function:
        attach_functions(model)
    return model
