"""`function_body`: the ONNX form of a custom op from its spec and one body builder.

    @function_body("KernelApply")
    def kernel_apply_body(opset: int) -> list[onnx.NodeProto]: ...

The builder returns the op's meaning in standard ONNX ops (the portable path: stock ONNX
Runtime inlines the model-local FunctionProto when no fast kernel is registered). Everything
else comes from the op's `OpSpec` (rtdenoise.ops), here, once for every op: the
`onnx.defs.OpSchema` of the node `rtdenoise.<Name>`, the onnxscript translation that the torch
exporter calls for `torch.ops.rtdenoise.<torch_name>.default`, and the FunctionProto.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import onnx
from onnx import defs, helper
from onnxscript import values

from rtdenoise.ops import DOMAIN, DOMAIN_VERSION, OpSpec
from rtdenoise.ops.spec import form_decorator

OPSET = 18  # ai.onnx opset of exported models (ORT 1.31 accepts <= 26)
IR_VERSION = 10  # ORT 1.31 accepts <= 13; onnx 1.23's make_model default (14) is refused

CUSTOM_OPSET = values.Opset(DOMAIN, DOMAIN_VERSION)
BodyBuilder = Callable[[int], list[onnx.NodeProto]]


def make_schema(spec: OpSpec) -> defs.OpSchema:
    """OpSchema of `rtdenoise.<Name>`: float tensors everywhere, INT attributes, required
    except the spec's optional ones (which carry their value as the default)."""
    param = defs.OpSchema.FormalParameter
    attr = defs.OpSchema.Attribute
    return defs.OpSchema(
        spec.name,
        DOMAIN,
        DOMAIN_VERSION,
        spec.doc,
        inputs=[param(a.name, "T") for a in spec.inputs],
        outputs=[param(a.name, "T") for a in spec.outputs],
        type_constraints=[("T", ["tensor(float)"], "float32 tensors")],
        attributes=[
            attr(a, helper.make_attribute(a, spec.optional_attrs[a]), a)
            if a in spec.optional_attrs
            else attr(a, defs.OpSchema.AttrType.INT, a, required=True)
            for a in spec.attrs
        ],
    )


def make_translation(spec: OpSpec, op: values.Op) -> Callable:
    """fn(*inputs, *int attributes) -> the custom node, with the named signature the
    exporter's dispatcher matches against the torch op's schema."""
    n = len(spec.inputs)

    def translation(*args):
        return op(*args[:n], **dict(zip(spec.attrs, args[n:], strict=True)))

    params = [
        inspect.Parameter(a.name, inspect.Parameter.POSITIONAL_OR_KEYWORD) for a in spec.inputs
    ]
    params += [
        inspect.Parameter(a, inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=int)
        for a in spec.attrs
    ]
    translation.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    translation.__annotations__ = {a: int for a in spec.attrs}
    translation.__name__ = f"{spec.torch_name}_translation"
    return translation


@dataclass(frozen=True)
class OnnxForm:
    """The ONNX form of one op: schema, exporter translation and FunctionProto builder."""

    spec: OpSpec
    schema: defs.OpSchema
    translation: Callable
    body: BodyBuilder

    @property
    def name(self) -> str:
        return self.spec.name

    def build_function(self, opset: int) -> onnx.FunctionProto:
        """Model-local FunctionProto `rtdenoise.<Name>` over the standard opset `opset`; an
        optional attribute carries its value as the default (a node may omit it)."""
        optional = self.spec.optional_attrs
        return helper.make_function(
            DOMAIN,
            self.spec.name,
            list(self.spec.input_names),
            list(self.spec.output_names),
            self.body(opset),
            opset_imports=[helper.make_opsetid("", opset)],
            attributes=[a for a in self.spec.attrs if a not in optional],
            attribute_protos=[helper.make_attribute(a, v) for a, v in optional.items()],
            doc_string=self.spec.doc,
        )


ONNX_FORMS: dict[str, OnnxForm] = {}


def _onnx_form(spec: OpSpec, body: BodyBuilder) -> OnnxForm:
    schema = make_schema(spec)
    op = values.Op(CUSTOM_OPSET, spec.name, schema)  # an onnxscript Op must carry its schema
    return OnnxForm(spec, schema, make_translation(spec, op), body)


# Decorator: a body builder (opset -> standard-op nodes over the spec's input and output
# names; attributes via `attr_const`) -> the op's registered OnnxForm.
function_body = form_decorator(ONNX_FORMS, "ONNX function body", _onnx_form)


def int_const(name: str, value: list[int] | int) -> onnx.NodeProto:
    """Constant int64 node: a 1-D tensor for a list, a scalar for an int."""
    if isinstance(value, int):
        return helper.make_node("Constant", [], [name], value_int=value)
    return helper.make_node("Constant", [], [name], value_ints=value)


def float_const(name: str, value: float) -> onnx.NodeProto:
    """Constant scalar float32 node."""
    return helper.make_node(
        "Constant", [], [name], value=helper.make_tensor("", onnx.TensorProto.FLOAT, [], [value])
    )


def attr_const(name: str, attr: str) -> onnx.NodeProto:
    """Constant scalar int64 node holding the function attribute `attr`."""
    node = helper.make_node("Constant", [], [name])
    ref = onnx.AttributeProto()
    ref.name = "value_int"
    ref.type = onnx.AttributeProto.INT
    ref.ref_attr_name = attr
    node.attribute.append(ref)
    return node


def if_branch(
    graph_name: str, prefix: str, nodes: list[onnx.NodeProto], outputs: Sequence[str]
) -> onnx.GraphProto:
    """A subgraph of an If on a function attribute: `nodes` with the function's `outputs`
    renamed `<prefix>_<output>` (each branch declares its own), float tensors."""
    rename = {o: f"{prefix}_{o}" for o in outputs}
    for node in nodes:
        node.input[:] = [rename.get(i, i) for i in node.input]
        node.output[:] = [rename.get(o, o) for o in node.output]
    values = [
        helper.make_tensor_value_info(rename[o], onnx.TensorProto.FLOAT, None) for o in outputs
    ]
    return helper.make_graph(nodes, graph_name, [], values)


def softmax_axis1(x: str, out: str, prefix: str, opset: int) -> list[onnx.NodeProto]:
    """Nodes computing `out` = softmax over axis 1 of `x`, spelled out (ReduceMax, Sub, Exp,
    ReduceSum, Div; intermediate names start with `prefix`): ORT's Softmax(axis=1) on NCHW
    transposes internally and was 4x slower at 720p (400 ms vs 92 ms on KernelFusion's)."""
    mk = helper.make_node
    names = ("axis", "top", "shifted", "e", "total")
    axis, top, shifted, e, total = (f"{prefix}{n}" for n in names)
    if opset >= 18:  # axes became an input of ReduceMax in opset 18
        reduce_max = mk("ReduceMax", [x, axis], [top], keepdims=1)
    else:
        reduce_max = mk("ReduceMax", [x], [top], axes=[1], keepdims=1)
    return [
        int_const(axis, [1]),
        reduce_max,
        mk("Sub", [x, top], [shifted]),
        mk("Exp", [shifted], [e]),
        mk("ReduceSum", [e, axis], [total], keepdims=1),
        mk("Div", [e, total], [out]),
    ]
