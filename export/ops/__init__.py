"""ONNX form of the custom ops: one function body per op (named like its spec in rtdenoise.ops).

Importing this package imports every module, which registers each op's `OnnxForm` (schema,
exporter translation, FunctionProto builder) in `ONNX_FORMS`. `attach_functions` adds the
bodies of the ops a model uses; `single_op_model` builds a one-node model for tests and
benchmarks. See docs/architecture.md, "Adding an op".
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import onnx
from onnx import TensorProto, helper

from rtdenoise.ops import DOMAIN, DOMAIN_VERSION, import_submodules, plugins

from .base import IR_VERSION, ONNX_FORMS, OPSET, OnnxForm, function_body

import_submodules(__name__)
plugins.load_modules(plugins.ONNX_FORMS)  # forms of other packages' ops (docs/your-own-model.md)

__all__ = [
    "DOMAIN",
    "DOMAIN_VERSION",
    "IR_VERSION",
    "ONNX_FORMS",
    "OPSET",
    "OnnxForm",
    "attach_functions",
    "custom_translation_table",
    "function_body",
    "function_protos",
    "single_op_model",
    "used_ops",
]


def custom_translation_table() -> dict:
    """{torch.ops.rtdenoise.<op>.default: onnxscript translation} for torch.onnx.export."""
    from rtdenoise.models.ops import TORCH_OPS

    return {TORCH_OPS[name].overload(): form.translation for name, form in ONNX_FORMS.items()}


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
            if node.op_type not in ONNX_FORMS:
                raise ValueError(f"unknown custom op {DOMAIN}.{node.op_type}")
            names.add(node.op_type)
    return sorted(names)


def function_protos(used_op_names: Sequence[str], opset: int = OPSET) -> list[onnx.FunctionProto]:
    """Model-local FunctionProtos (bodies in ai.onnx opset `opset`) for the named ops."""
    return [ONNX_FORMS[name].build_function(opset) for name in sorted(set(used_op_names))]


def attach_functions(model: onnx.ModelProto) -> onnx.ModelProto:
    """Add the FunctionProto of every rtdenoise op the graph uses (in place; returns `model`).

    Also adds the `rtdenoise` opset import (version 1). Existing rtdenoise functions are
    replaced, so calling it twice is harmless.
    """
    names = used_ops(model)
    keep = [f for f in model.functions if not (f.domain == DOMAIN and f.name in ONNX_FORMS)]
    del model.functions[:]
    model.functions.extend(keep)
    model.functions.extend(function_protos(names, _model_opset(model)))
    if names and not any(i.domain == DOMAIN for i in model.opset_import):
        model.opset_import.append(helper.make_opsetid(DOMAIN, DOMAIN_VERSION))
    return model


Dims = Sequence[int | str | None]


def dynamic_shapes(op_name: str) -> list[list[str]]:
    """One fully dynamic shape per input of `op_name` (a dim name per input and axis)."""
    spec = ONNX_FORMS[op_name].spec
    return [[f"{a.name}_{i}" for i in range(a.rank)] for a in spec.inputs]


def single_op_model(
    op_name: str,
    input_shapes: Sequence[Dims] | None = None,
    attrs: dict[str, int] | None = None,
    with_function: bool = True,
) -> onnx.ModelProto:
    """A one-node model `rtdenoise.<op_name>` (IR 10, opset 18) for tests and benchmarks.

    input_shapes: one shape per op input, dims as ints or names (default: all dynamic);
    attrs: the int attributes (all required). with_function=False leaves the FunctionProto
    out, so the model only runs when the fast kernels are registered. Output shapes follow
    the spec's rule when every input dim is a number, else only their rank is declared.
    """
    spec = ONNX_FORMS[op_name].spec
    attrs = dict(attrs or {})
    input_shapes = [list(s) for s in (input_shapes or dynamic_shapes(op_name))]
    if set(attrs) != set(spec.attrs):
        raise ValueError(f"{op_name} needs attributes {list(spec.attrs)}, got {sorted(attrs)}")
    if all(isinstance(d, int) for s in input_shapes for d in s):
        spec.validate_call([tuple(s) for s in input_shapes], attrs)
        out_shapes: list[Dims] = [list(s) for s in spec.output_shapes(input_shapes, attrs)]
    else:
        out_shapes = [[None] * a.rank for a in spec.outputs]
    node = helper.make_node(
        op_name, list(spec.input_names), list(spec.output_names), domain=DOMAIN, **attrs
    )
    graph = helper.make_graph(
        [node],
        f"single_{op_name}",
        [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape))
            for name, shape in zip(spec.input_names, input_shapes, strict=True)
        ],
        [
            helper.make_tensor_value_info(name, TensorProto.FLOAT, list(shape))
            for name, shape in zip(spec.output_names, out_shapes, strict=True)
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
