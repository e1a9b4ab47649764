"""The learning of an online model under an ONNX `If`: a frozen frame runs no backward pass.

An online model's graph (Choi24, `rtdenoise.online`) computes each learned state as
`Where(learn, stepped, kept)` (`models.online.adam_step`): the gradient and the optimiser step
`stepped`, or the state as it came in, `kept`, where the host's `freeze` control is 1. ONNX
Runtime runs both sides of a `Where`, so a frozen frame (`--no-online`, the frames
`--learn-every` skips) paid for the whole backward pass and discarded it.

`branch_learning` moves the nodes that only the stepped values need (the backward pass and the
optimiser step: ancestors of `stepped` that no other output, `kept` or the condition needs) into
the then-branch of one `If` on that condition; its else-branch passes `kept` through. The `If`
takes the place of the `Where` nodes (same output names). Every node that the displayed output,
the history, the loss or `kept` need stays in the main graph as it was, so a frozen frame
computes exactly what it computed before, and a learning frame runs the same nodes as before.

Chosen over a second, inference-only graph in the same file (the host choosing the session per
frame) by measurement (benchmarks/README.md, "Frozen frames run no backward"): the `If` costs a
learning frame nothing measurable and a frozen frame runs as fast as the pruned graph, with one
session, one set of initialisers and no change to the contract (a host that knows nothing of it
still works).
"""

from __future__ import annotations

from collections.abc import Iterable

import onnx
from onnx import helper

# what may sit between a learned state's Where and its graph output
_PASS_THROUGH = ("Reshape", "Identity", "Squeeze", "Unsqueeze")
THEN, ELSE = "learn", "frozen"


def learned_outputs(online: dict) -> list[str]:
    """The graph outputs of the learned states `rtdenoise.online` names (weights, moments, step)."""
    names = [online.get("parameters"), *online.get("moments", []), online.get("step")]
    return [f"state_next.{n}" for n in names if n]


def _ancestors(nodes: list[onnx.NodeProto], names: Iterable[str]) -> set[int]:
    producer = {out: i for i, node in enumerate(nodes) for out in node.output}
    seen: set[int] = set()
    todo = [producer[n] for n in names if n in producer]
    while todo:
        i = todo.pop()
        if i not in seen:
            seen.add(i)
            todo.extend(producer[x] for x in _reads(nodes[i]) if x in producer)
    return seen


def _reads(node: onnx.NodeProto) -> set[str]:
    """The tensors a node reads: its inputs and what its subgraphs read from the outer scope."""
    names = {x for x in node.input if x}
    for g in subgraphs(node):
        made = {i.name for i in g.input} | {t.name for t in g.initializer}
        made |= {o for n in g.node for o in n.output}
        names |= {x for n in g.node for x in _reads(n)} - made
    return names


def _toposort(nodes: list[onnx.NodeProto], available: set[str]) -> list[onnx.NodeProto]:
    """`nodes` in an order where each comes after the producers of what it reads (stable)."""
    producer = {out: i for i, node in enumerate(nodes) for out in node.output}
    order: list[onnx.NodeProto] = []
    done: set[int] = set()
    for start in range(len(nodes)):
        stack = [(start, False)]
        while stack:
            i, expanded = stack.pop()
            if i in done:
                continue
            if expanded:
                done.add(i)
                order.append(nodes[i])
                continue
            stack.append((i, True))
            for x in sorted(_reads(nodes[i]) - available, reverse=True):
                if x in producer and producer[x] not in done:
                    stack.append((producer[x], False))
    return order


def branch_learning(proto: onnx.ModelProto, online: dict | None) -> bool:
    """Put the update of `online`'s learned states under an `If` (module docstring), in place.
    False (nothing changed) where there is nothing to branch: not an online model, or a graph
    already branched."""
    if not online:
        return False
    graph = proto.graph
    nodes = list(graph.node)
    producer = {out: i for i, node in enumerate(nodes) for out in node.output}
    outputs = learned_outputs(online)
    wheres = []
    for name in outputs:
        i = producer.get(name)
        while i is not None and nodes[i].op_type in _PASS_THROUGH:
            i = producer.get(nodes[i].input[0])
        if i is None or nodes[i].op_type == "If":
            return False
        if nodes[i].op_type != "Where":
            raise ValueError(f"{name}: made by a {nodes[i].op_type}, not the update's Where")
        wheres.append(i)
    conditions = {nodes[i].input[0] for i in wheres}
    if len(conditions) != 1:
        raise ValueError(f"the learned states are gated by {len(conditions)} conditions, not one")
    (condition,) = conditions
    stepped = [nodes[i].input[1] for i in wheres]
    kept = [nodes[i].input[2] for i in wheres]
    others = {o.name for o in graph.output} - set(outputs)
    needed = _ancestors(nodes, others | {condition, *kept})
    update = _ancestors(nodes, stepped) - needed
    if any(i in update for i in wheres):
        raise ValueError("a learned state's Where feeds its own update")

    types = {v.name: v.type for v in list(graph.value_info) + list(graph.output)}

    def typed(name: str, like: str) -> onnx.ValueInfoProto:
        info = onnx.ValueInfoProto(name=name)
        if like in types:
            info.type.CopyFrom(types[like])
        else:
            info.type.tensor_type.elem_type = onnx.TensorProto.FLOAT
        return info

    made_inside = {o for i in update for o in nodes[i].output}
    then_nodes = [nodes[i] for i in sorted(update)]
    then_outputs, else_nodes, else_outputs = [], [], []
    for k, (w, s, x) in enumerate(zip(wheres, stepped, kept, strict=True)):
        out = nodes[w].output[0]
        if s not in made_inside:  # a graph output must be made inside its graph
            then_nodes.append(helper.make_node("Identity", [s], [f"{out}.{THEN}"]))
            s = f"{out}.{THEN}"
        then_outputs.append(typed(s, out))
        else_nodes.append(helper.make_node("Identity", [x], [f"{out}.{ELSE}"], name=f"kept_{k}"))
        else_outputs.append(typed(f"{out}.{ELSE}", out))
    inner = {o for n in then_nodes for o in n.output}
    then_graph = helper.make_graph(
        then_nodes,
        "learning_step",
        [],
        then_outputs,
        value_info=[v for v in graph.value_info if v.name in inner and v.name not in stepped],
    )
    else_graph = helper.make_graph(else_nodes, "frozen_step", [], else_outputs)
    branch = helper.make_node(
        "If",
        [condition],
        [nodes[w].output[0] for w in wheres],
        name="learning_step",
        then_branch=then_graph,
        else_branch=else_graph,
        doc_string="backward pass and optimiser step where the host's freeze control is 0 "
        "(export/learning_branch.py)",
    )
    moved = update | set(wheres)
    rest = [n for i, n in enumerate(nodes) if i not in moved] + [branch]
    available = {i.name for i in graph.input} | {t.name for t in graph.initializer}
    ordered = _toposort(rest, available)
    del graph.node[:]
    graph.node.extend(ordered)
    kept_info = [v for v in graph.value_info if v.name not in inner]
    del graph.value_info[:]
    graph.value_info.extend(kept_info)
    return True


def subgraphs(node: onnx.NodeProto) -> list[onnx.GraphProto]:
    """The graphs among `node`'s attributes (an `If`'s branches), themselves (not copies)."""
    found = []
    for attr in node.attribute:
        if attr.type == onnx.AttributeProto.GRAPH:
            found.append(attr.g)
        found.extend(attr.graphs)
    return found


def all_nodes(graph: onnx.GraphProto) -> Iterable[onnx.NodeProto]:
    """Every node of `graph` and of its subgraphs, depth first (the nodes themselves)."""
    for node in graph.node:
        yield node
        for g in subgraphs(node):
            yield from all_nodes(g)


__all__ = ["all_nodes", "branch_learning", "learned_outputs", "subgraphs"]
