"""Custom-op attributes checked against the model's static shapes when it is loaded.

The fast kernels run each op's spec `check` on the real tensors, but the portable bodies
(ONNX functions) have no such check: a node whose attributes contradict its inputs
(SoftmaxKernelApply kernel_size=5 on 49-channel logits) gave a finite, wrong image on the
portable path. So `check_custom_nodes` reads the main graph's nodes of the rtdenoise domain,
their int attributes and the shapes the exporter recorded (graph inputs, value_info,
initializers), and runs the spec's `validate_call` on them. Symbolic sizes are the
exporter's expressions (`16*hb`, `8*s3`): every symbol is given one value, so that the
expressions keep their ratios (a half-resolution input stays half), tried with two values;
the node is refused only when both fail. A node whose inputs lack a recorded shape, or an
expression that is not plain arithmetic, is left to the run. The
protobuf is read with the same wire-format reader as `external_data.py` (no `onnx` here).
"""

from __future__ import annotations

import ast

from rtdenoise.ops import DOMAIN, SPECS

from .errors import InputError
from .protobuf import (
    MODEL_GRAPH,
    Malformed,
    fields,
    length_delimited,
    rewrite_graph_fields,
    varint,
    varint_field,
)

# Field numbers (onnx/onnx.proto3).

_GRAPH_NODE, _GRAPH_INIT, _GRAPH_INPUT, _GRAPH_OUTPUT, _GRAPH_VALUE_INFO = 1, 5, 11, 12, 13
_NODE_INPUT, _NODE_OP, _NODE_DOMAIN, _NODE_ATTR, _NODE_NAME = 1, 4, 7, 5, 3
_ATTR_NAME, _ATTR_I, _ATTR_TYPE, _ATTR_INT = 1, 3, 20, 2  # AttributeProto.INT = 2
_VI_NAME, _VI_TYPE, _TYPE_TENSOR, _TENSOR_SHAPE, _SHAPE_DIM = 1, 2, 1, 2, 1
_DIM_VALUE, _DIM_PARAM = 1, 2
_INIT_DIMS, _INIT_NAME = 1, 8
_SYMBOL_VALUES = (4, 6)  # each symbol's value in the two tries (16*hb -> 64, then 96)

Dim = int | str


def _text(v: int | memoryview) -> str:
    return bytes(v).decode("utf-8", "replace") if isinstance(v, memoryview) else ""


def _signed(v: int) -> int:
    return v - (1 << 64) if v >= 1 << 63 else v


def _value_info(buf: memoryview) -> tuple[str, list[Dim] | None]:
    name, dims = "", None
    for n, v in fields(buf):
        if n == _VI_NAME:
            name = _text(v)
        elif n == _VI_TYPE and isinstance(v, memoryview):
            for tn, tv in fields(v):
                if tn == _TYPE_TENSOR and isinstance(tv, memoryview):
                    for sn, sv in fields(tv):
                        if sn == _TENSOR_SHAPE and isinstance(sv, memoryview):
                            dims = []
                            for dn, dv in fields(sv):
                                if dn == _SHAPE_DIM and isinstance(dv, memoryview):
                                    dim: Dim = "?"
                                    for kn, kv in fields(dv):
                                        if kn == _DIM_VALUE and isinstance(kv, int):
                                            dim = kv
                                        elif kn == _DIM_PARAM:
                                            dim = _text(kv) or "?"
                                    dims.append(dim)
    return name, dims


def _initializer(buf: memoryview) -> tuple[str, list[Dim]]:
    name, dims = "", []
    for n, v in fields(buf):
        if n == _INIT_NAME:
            name = _text(v)
        elif n == _INIT_DIMS:
            if isinstance(v, int):
                dims.append(v)
            else:  # packed
                i = 0
                while i < len(v):
                    d, i = varint(v, i)
                    dims.append(d)
    return name, dims


def _graph(data: bytes) -> memoryview | None:
    for n, v in fields(memoryview(data)):
        if n == MODEL_GRAPH and isinstance(v, memoryview):
            return v
    return None


def custom_op_types(data: bytes) -> frozenset[str]:
    """The op types of the main graph's nodes of the rtdenoise domain (empty for a file that
    is not a model): what a fast path must hold to run the model."""
    try:
        graph = _graph(data)
        if graph is None or DOMAIN.encode() not in bytes(graph):
            return frozenset()
        found = set()
        for n, v in fields(graph):
            if n != _GRAPH_NODE or not isinstance(v, memoryview):
                continue
            op, domain = "", ""
            for fn, fv in fields(v):
                if fn == _NODE_OP:
                    op = _text(fv)
                elif fn == _NODE_DOMAIN:
                    domain = _text(fv)
            if domain == DOMAIN:
                found.add(op)
        return frozenset(found)
    except Malformed:
        return frozenset()


def check_custom_nodes(data: bytes, source: str) -> int:
    """InputError naming the model, the node and the problem when a custom node's int
    attributes contradict its inputs' recorded shapes; returns the number of nodes checked."""
    try:
        graph = _graph(data)
        if graph is None or DOMAIN.encode() not in bytes(graph):
            return 0
        shapes: dict[str, list[Dim]] = {}
        nodes = []
        for n, v in fields(graph):
            if not isinstance(v, memoryview):
                continue
            if n in (_GRAPH_INPUT, _GRAPH_OUTPUT, _GRAPH_VALUE_INFO):
                name, dims = _value_info(v)
                if dims is not None:
                    shapes[name] = dims
            elif n == _GRAPH_INIT:
                name, dims = _initializer(v)
                shapes[name] = dims
            elif n == _GRAPH_NODE:
                nodes.append(v)
        checked = 0
        for node in nodes:
            op, domain, name, inputs, attrs = "", "", "", [], {}
            for fn, fv in fields(node):
                if fn == _NODE_OP:
                    op = _text(fv)
                elif fn == _NODE_DOMAIN:
                    domain = _text(fv)
                elif fn == _NODE_NAME:
                    name = _text(fv)
                elif fn == _NODE_INPUT:
                    inputs.append(_text(fv))
                elif fn == _NODE_ATTR and isinstance(fv, memoryview):
                    key, value = "", None
                    for an, av in fields(fv):
                        if an == _ATTR_NAME:
                            key = _text(av)
                        elif an == _ATTR_I and isinstance(av, int):
                            value = _signed(av)
                    if value is not None:
                        attrs[key] = value
            spec = SPECS.get(op)
            if domain != DOMAIN or spec is None or any(i not in shapes for i in inputs):
                continue
            error = None
            for value in _SYMBOL_VALUES:
                concrete = [_concrete(shapes[i], value) for i in inputs]
                if any(c is None for c in concrete):
                    break  # a size the check cannot evaluate: left to the run
                try:
                    spec.validate_call(concrete, attrs)
                except ValueError as exc:
                    error = error or exc
                    continue
                error = None
                break
            if error is not None:
                exc = error
                where = f"node {name!r} ({op})" if name else f"a {op} node"
                shown = ", ".join(f"{i} {tuple(shapes[i])}" for i in inputs)
                raise InputError(
                    f"{source}: {where} contradicts its inputs: {exc} (inputs {shown}, "
                    f"attributes {attrs}); its portable body would give a wrong image"
                ) from None
            checked += 1
        return checked
    except Malformed:
        return 0  # not a model: ONNX Runtime's loader says so, in its words


def _concrete(dims: list[Dim], value: int) -> tuple[int, ...] | None:
    """The shape with every symbol of its expressions set to `value`; None if some dim is
    unknown or not plain arithmetic."""
    out = []
    for d in dims:
        v = d if isinstance(d, int) else _evaluate(d, value)
        if v is None or v < 1:
            return None
        out.append(v)
    return tuple(out)


def _evaluate(expr: str, value: int) -> int | None:
    try:
        tree = ast.parse(expr, mode="eval").body
    except (SyntaxError, ValueError):
        return None

    def ev(node: ast.AST) -> int:
        if isinstance(node, ast.Constant) and isinstance(node.value, int):
            return node.value
        if isinstance(node, ast.Name):
            return value
        if isinstance(node, ast.BinOp):
            a, b = ev(node.left), ev(node.right)
            if isinstance(node.op, ast.Add):
                return a + b
            if isinstance(node.op, ast.Sub):
                return a - b
            if isinstance(node.op, ast.Mult):
                return a * b
            if isinstance(node.op, (ast.FloorDiv, ast.Div)) and b:
                return a // b
        raise ValueError(expr)

    try:
        return ev(tree)
    except (ValueError, RecursionError):
        return None


__all__ = ["check_custom_nodes"]


def fill_optional_attributes(data: bytes) -> bytes | None:
    """The model with each omitted optional attribute (`OpSpec.optional_attrs`) of its main
    graph's rtdenoise nodes written out with its value; None when no node omits one (or the
    bytes are not a model). onnxruntime-extensions refuses a node without one of the op's
    declared attributes, so a model exported before the attribute existed (every shipped demo
    lacks TemporalAccumulation's per_tap) is loaded through this on that bridge."""
    if DOMAIN.encode() not in data:
        return None
    try:
        return rewrite_graph_fields(data, _GRAPH_NODE, _filled_node)
    except Malformed:
        return None


def _filled_node(node: memoryview) -> bytes | None:
    op, domain, names = "", "", set()
    for fn, fv in fields(node):
        if fn == _NODE_OP:
            op = _text(fv)
        elif fn == _NODE_DOMAIN:
            domain = _text(fv)
        elif fn == _NODE_ATTR and isinstance(fv, memoryview):
            names.update(_text(av) for an, av in fields(fv) if an == _ATTR_NAME)
    spec = SPECS.get(op)
    if domain != DOMAIN or spec is None:
        return None
    missing = [a for a in spec.optional_attrs if a not in names]
    if not missing:
        return None
    added = b"".join(
        length_delimited(
            _NODE_ATTR,
            length_delimited(_ATTR_NAME, a.encode())
            + varint_field(_ATTR_I, spec.optional_attrs[a])
            + varint_field(_ATTR_TYPE, _ATTR_INT),
        )
        for a in missing
    )
    return bytes(node) + added
