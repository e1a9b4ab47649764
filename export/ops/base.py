"""Shared pieces of the ONNX form of the custom ops (design.md s.2, form 2).

Each op module defines an `OpSpec`: the `onnx.defs.OpSchema` of the node
`rtdenoise.<Op>` (domain `rtdenoise`, version 1), the onnxscript translation function the
torch exporter calls for `torch.ops.rtdenoise.<op>.default`, and a builder for the
model-local `FunctionProto` whose body spells the op in standard ONNX ops (the portable
path: stock ONNX Runtime inlines it when no fast kernel is registered).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import onnx
from onnx import defs, helper
from onnxscript import values

DOMAIN = "rtdenoise"
DOMAIN_VERSION = 1
OPSET = 18  # ai.onnx opset of exported models (ORT 1.31 accepts <= 26)
IR_VERSION = 10  # ORT 1.31 accepts <= 13; onnx 1.23's make_model default (14) is refused

CUSTOM_OPSET = values.Opset(DOMAIN, DOMAIN_VERSION)


@dataclass(frozen=True)
class OpSpec:
    """Everything the exporter needs to know about one custom op.

    name: ONNX op_type (e.g. "KernelApply"); torch_name: the custom op's name in the
    `torch.ops.rtdenoise` namespace (e.g. "kernel_apply"); int_attrs: the node's
    attribute names (all INT, all required); build_function(opset) returns the FunctionProto;
    example_inputs(shape, attrs, rng) gives float32 inputs for an (N, C, H, W) image shape
    (tests, benchmarks); default_attrs are typical attribute values; output_shape(input_shapes,
    attrs) gives the output shapes of a single-op model (None: every output like input 0).
    """

    name: str
    torch_name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    int_attrs: tuple[str, ...]
    schema: defs.OpSchema
    translation: Callable
    build_function: Callable[[int], onnx.FunctionProto]
    example_inputs: Callable[[tuple[int, ...], dict, np.random.Generator], list[np.ndarray]]
    default_attrs: dict[str, int] = field(default_factory=dict)
    output_shape: Callable[[list, dict], list[list]] | None = None

    def torch_op(self):
        """The `torch.ops.rtdenoise.<torch_name>.default` overload (imports the torch forms)."""
        import torch

        import rtdenoise.models.ops  # noqa: F401  (registers the custom ops)

        return getattr(getattr(torch.ops, DOMAIN), self.torch_name).default


def make_schema(
    name: str,
    inputs: tuple[str, ...],
    outputs: tuple[str, ...],
    int_attrs: tuple[str, ...],
    doc: str,
) -> defs.OpSchema:
    """OpSchema with float tensors everywhere and required INT attributes."""
    param = defs.OpSchema.FormalParameter
    return defs.OpSchema(
        name,
        DOMAIN,
        DOMAIN_VERSION,
        doc,
        inputs=[param(i, "T") for i in inputs],
        outputs=[param(o, "T") for o in outputs],
        type_constraints=[("T", ["tensor(float)"], "float32 tensors")],
        attributes=[
            defs.OpSchema.Attribute(a, defs.OpSchema.AttrType.INT, a, required=True)
            for a in int_attrs
        ],
    )


def make_op(schema: defs.OpSchema) -> values.Op:
    """An onnxscript Op that emits the custom node (it must carry the schema)."""
    return values.Op(CUSTOM_OPSET, schema.name, schema)


def int_const(name: str, value: list[int] | int) -> onnx.NodeProto:
    """Constant int64 node: a 1-D tensor for a list, a scalar for an int."""
    if isinstance(value, int):
        return helper.make_node("Constant", [], [name], value_int=value)
    return helper.make_node("Constant", [], [name], value_ints=value)


def attr_const(name: str, attr: str) -> onnx.NodeProto:
    """Constant scalar int64 node holding the function attribute `attr`."""
    node = helper.make_node("Constant", [], [name])
    ref = onnx.AttributeProto()
    ref.name = "value_int"
    ref.type = onnx.AttributeProto.INT
    ref.ref_attr_name = attr
    node.attribute.append(ref)
    return node


def make_function(
    spec_name: str,
    inputs: tuple[str, ...],
    outputs: tuple[str, ...],
    int_attrs: tuple[str, ...],
    nodes: list[onnx.NodeProto],
    opset: int,
    doc: str,
) -> onnx.FunctionProto:
    """Model-local FunctionProto `rtdenoise.<spec_name>` over the standard opset `opset`."""
    return helper.make_function(
        DOMAIN,
        spec_name,
        list(inputs),
        list(outputs),
        nodes,
        opset_imports=[helper.make_opsetid("", opset)],
        attributes=list(int_attrs),
        doc_string=doc,
    )
