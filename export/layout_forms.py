"""Second forms of convs for AVX-512's 16-channel NCHWc block, under an `If` that ONNX Runtime
resolves when it loads the model.

ORT's blocked convs (NchwcTransformer) work in channel blocks of 8 with AVX2 and 16 with
AVX-512. The export pads conv widths to multiples of 8 (conv_widths.py), which is one layout
for AVX2 and a wasteful one for AVX-512. Two convs of demo:nbg at 720p on an AVX-512 Xeon:

- **Row phases.** A conv with 8 output channels is computed 16 wide, half thrown away (nbg's
  last GuideNet conv, 32 -> 8, 5 x 5: 107-142 ms of a 470-710 ms frame). Its row-phase form
  computes the even and the odd output rows as the two halves of one 16-wide conv with stride
  2 down the rows: kernel rows kh + 1, the first half the filters over rows 0..kh-1 (a zero row
  last), the second half the same filters one row further down (a zero row first), one more
  row of bottom padding. Channel c of half p at row y' is output row 2 y' + p, exactly (the
  same products summed; a zero tap adds +0). A Reshape / Transpose / Reshape interleaves the
  rows; a Slice keeps the output's height (the form computes an even number of rows). AVX-512:
  0.6x the multiply-adds of the padded form; AVX2: 1.2x the plain form's.
- **Zero input channels dropped.** A conv reading a concatenation padded with zero channels
  to 16 (13 -> 16, nbg's GuideNet input) needs a ReorderInput into blocks with AVX2 or AVX-512;
  with AVX-512 a conv with fewer input channels than the block reads plain NCHW directly. Its
  form without the zeros skips the reorder and the zeros (with AVX2, 13 channels would not be
  blocked at all).

`layout_forms` puts each such conv (with the activation ORT fuses into it, when that is the
conv's only reader, and a padded concatenation it alone reads) under `If(layout.nchwc16)`, the
AVX-512 form in the then branch and the original nodes in the else branch. The flag is a plain
initializer (False in the file: the original), so ORT's constant folding inlines one branch
before its layout transformers run; the runtime writes the flag for the CPU it runs on
(runtime/layout.py). A row-phase conv is rewritten only when its output height and width are
a graph input's (from shape inference): the reshapes and the Slice read the size from that
input, not from the conv's blocked input, which would cost a reorder.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from .conv_widths import auto_pad, ints_attribute, is_standard
from .graph_index import GraphIndex

LAYOUT_FLAG = "layout.nchwc16"  # runtime/layout.py writes it: keep the two names in step
BLOCK = 16  # AVX-512's NCHWc block
FUSED_ACTIVATIONS = ("Relu", "LeakyRelu", "Sigmoid", "Tanh", "HardSigmoid")  # ORT fuses these
# Row phases pay for their interleave only on a conv with enough taps per output (input
# channels x kernel area): nbg's 32 x 5 x 5 = 800 saved 40 ms of a 720p frame, afn's fusion
# conv 16 x 3 x 3 = 144 nothing (2026-12-07, AVX-512 Xeon).
MIN_PHASE_TAPS = 400


class _Graph(GraphIndex):
    """A GraphIndex of the main graph with its inferred values and its graph inputs."""

    def __init__(self, proto: onnx.ModelProto) -> None:
        super().__init__(proto.graph)
        inferred = onnx.shape_inference.infer_shapes(proto).graph
        self.values = {v.name: v for v in (*inferred.input, *inferred.value_info, *inferred.output)}
        self.inputs = [v for v in proto.graph.input if v.name not in self.consts]

    def fused_activation(self, conv: onnx.NodeProto) -> onnx.NodeProto | None:
        """The activation ORT fuses into `conv`: its only reader, of a fusable type."""
        reader = self.sole_reader(conv.output[0])
        if reader is not None and reader.op_type in FUSED_ACTIVATIONS and is_standard(reader):
            return reader
        return None


def _is(a: onnx.NodeProto | None, b: onnx.NodeProto) -> bool:
    """The same node (protobuf hands out new wrappers: compare outputs, not identity)."""
    return a is not None and list(a.output) == list(b.output)


def _plain_conv(node: onnx.NodeProto, g: _Graph) -> bool:
    """A 2-D Conv with stride and dilation 1, group 1, weights and bias initializers."""
    return (
        node.op_type == "Conv"
        and is_standard(node)
        and len(node.input) == 3
        and node.input[1] in g.consts
        and node.input[2] in g.consts
        and g.consts[node.input[1]].ndim == 4
        and next((a.i for a in node.attribute if a.name == "group"), 1) == 1
        and all(s == 1 for s in ints_attribute(node, "strides") or [1, 1])
        and all(d == 1 for d in ints_attribute(node, "dilations") or [1, 1])
        and auto_pad(node) == b"NOTSET"
    )


def _shape(value: onnx.ValueInfoProto) -> list[int | str]:
    return [
        d.dim_value if d.HasField("dim_value") else d.dim_param
        for d in value.type.tensor_type.shape.dim
    ]


def _branch(
    name: str,
    nodes: list[onnx.NodeProto],
    result: str,
    like: onnx.ValueInfoProto,
    consts: dict[str, np.ndarray] | None = None,
) -> onnx.GraphProto:
    """An If branch: `nodes` (reading outer values by name), `consts` as its initializers,
    the value `result` shaped as `like` its output."""
    shape = _shape(like)
    out = helper.make_tensor_value_info(result, TensorProto.FLOAT, shape or None)
    initializers = [numpy_helper.from_array(v, k) for k, v in (consts or {}).items()]
    return helper.make_graph(nodes, name, [], [out], initializers)


def _activated(
    nodes: list[onnx.NodeProto], activation: onnx.NodeProto | None, source: str, tag: str
) -> str:
    """Append a copy of `activation` (if any) reading `source`; the name of the last value."""
    if activation is None:
        return source
    act = helper.make_node(activation.op_type, [source], [f"{tag}_act"])
    act.attribute.extend(activation.attribute)
    nodes.append(act)
    return f"{tag}_act"


def _replace_with_if(
    g: _Graph, moved: list[onnx.NodeProto], then_branch: onnx.GraphProto, tag: str
) -> None:
    """Replace `moved` (in graph order; the last one's output is the result, the others' are
    read only among them) by an If whose else branch is copies of them and whose then branch
    is `then_branch`, where the last of them stood."""
    graph = g.graph
    result = moved[-1].output[0]
    copies = []
    for node in moved:
        copies.append(onnx.NodeProto())
        copies[-1].CopyFrom(node)
    copies[-1].output[0] = f"{tag}_plain"
    else_branch = _branch(f"{tag}_plain", copies, f"{tag}_plain", g.values[result])
    node = helper.make_node(
        "If", [LAYOUT_FLAG], [result], name=tag, then_branch=then_branch, else_branch=else_branch
    )
    at = list(graph.node).index(moved[-1]) - (len(moved) - 1)  # after every input's producer
    for n in moved:
        graph.node.remove(n)
    graph.node.insert(at, node)


def _size_input(g: _Graph, result: str) -> tuple[int, str] | None:
    """(batch, a graph input with `result`'s height and width), or None when the batch is
    not a fixed number or no graph input has that size."""
    value = g.values.get(result)
    if value is None:
        return None
    dims = list(value.type.tensor_type.shape.dim)
    if len(dims) != 4 or not dims[0].HasField("dim_value"):
        return None

    def same(a, b) -> bool:
        if a.HasField("dim_value") and b.HasField("dim_value"):
            return a.dim_value == b.dim_value
        return a.HasField("dim_param") and b.HasField("dim_param") and a.dim_param == b.dim_param

    for v in g.inputs:
        vd = list(v.type.tensor_type.shape.dim)
        if len(vd) == 4 and same(vd[2], dims[2]) and same(vd[3], dims[3]):
            return int(dims[0].dim_value), v.name
    return None


def row_phases(g: _Graph, conv: onnx.NodeProto) -> bool:
    """The row-phase form of a conv with 8 (mod 16) output channels (module docstring)."""
    if not _plain_conv(conv, g):
        return False
    w, b = g.consts[conv.input[1]], g.consts[conv.input[2]]
    c, cin, kh, kw = w.shape
    if c % BLOCK != BLOCK // 2 or cin * kh * kw < MIN_PHASE_TAPS:
        return False
    activation = g.fused_activation(conv)
    moved = [conv] if activation is None else [conv, activation]
    size = _size_input(g, moved[-1].output[0])
    if size is None:
        return False
    batch, size_input = size
    tag = f"{conv.name or conv.output[0]}_rowphase"
    phases = np.zeros((2 * c, cin, kh + 1, kw), w.dtype)
    phases[:c, :, :kh] = w  # even output rows: rows 0..kh-1 of the window
    phases[c:, :, 1:] = w  # odd output rows: the window one row further down
    g.graph.initializer.extend(
        [
            numpy_helper.from_array(phases, f"{tag}.weight"),
            numpy_helper.from_array(np.concatenate([b, b]), f"{tag}.bias"),
        ]
    )
    pads = ints_attribute(conv, "pads") or [0, 0, 0, 0]
    nodes = [
        helper.make_node(
            "Conv",
            [conv.input[0], f"{tag}.weight", f"{tag}.bias"],
            [f"{tag}_conv"],
            pads=[pads[0], pads[1], pads[2] + 1, pads[3]],
            strides=[2, 1],
            kernel_shape=[kh + 1, kw],
        )
    ]
    last = _activated(nodes, activation, f"{tag}_conv", tag)
    nodes += [
        helper.make_node("Shape", [size_input], [f"{tag}_h"], start=2, end=3),
        helper.make_node("Shape", [size_input], [f"{tag}_w"], start=3, end=4),
        helper.make_node("Concat", [f"{tag}_lead5", f"{tag}_w"], [f"{tag}_shape5"], axis=0),
        helper.make_node("Concat", [f"{tag}_lead4", f"{tag}_w"], [f"{tag}_shape4"], axis=0),
        helper.make_node("Reshape", [last, f"{tag}_shape5"], [f"{tag}_halves"]),
        # (N, 2, C, H', W) -> (N, C, H', 2, W): row y' of half p becomes row 2 y' + p
        helper.make_node("Transpose", [f"{tag}_halves"], [f"{tag}_pairs"], perm=[0, 2, 3, 1, 4]),
        helper.make_node("Reshape", [f"{tag}_pairs", f"{tag}_shape4"], [f"{tag}_rows"]),
        helper.make_node(
            "Slice", [f"{tag}_rows", f"{tag}_zero", f"{tag}_h", f"{tag}_axis"], [f"{tag}_out"]
        ),
    ]
    consts = {
        f"{tag}_lead5": np.array([batch, 2, c, -1], np.int64),
        f"{tag}_lead4": np.array([batch, c, -1], np.int64),
        f"{tag}_zero": np.array([0], np.int64),
        f"{tag}_axis": np.array([2], np.int64),
    }
    then_branch = _branch(
        f"{tag}_phases", nodes, f"{tag}_out", g.values[moved[-1].output[0]], consts
    )
    _replace_with_if(g, moved, then_branch, tag)
    return True


def _zero_fill(g: _Graph, name: str) -> bool:
    """`name` is a ConstantOfShape of 0 (the zeros conv_widths.pad_conv_inputs appends)."""
    node = g.producer.get(name)
    if node is None or node.op_type != "ConstantOfShape" or not is_standard(node):
        return False
    value = next((a.t for a in node.attribute if a.name == "value"), None)
    return value is None or not numpy_helper.to_array(value).any()


def zero_inputs_dropped(g: _Graph, conv: onnx.NodeProto) -> bool:
    """The form without the zero channels of a conv reading a concatenation padded to one
    AVX-512 block (module docstring)."""
    if not _plain_conv(conv, g):
        return False
    concat = g.producer.get(conv.input[0])
    if (
        concat is None
        or concat.op_type != "Concat"
        or not is_standard(concat)
        or not _is(g.sole_reader(concat.output[0]), conv)
        or not _zero_fill(g, concat.input[-1])
        or not _is(g.sole_reader(concat.input[-1]), concat)
    ):
        return False
    w = g.consts[conv.input[1]]
    parts = [g.values.get(name) for name in concat.input[:-1]]
    counts = [_shape(v)[1] if v is not None and len(_shape(v)) == 4 else None for v in parts]
    if not all(isinstance(k, int) for k in counts):
        return False
    real = sum(counts)  # the channels before the zeros
    if w.shape[1] != BLOCK or not 0 < real < BLOCK or w[:, real:].any():
        return False
    activation = g.fused_activation(conv)
    fill = g.producer[concat.input[-1]]
    moved = [fill, concat, conv] + ([activation] if activation is not None else [])
    tag = f"{conv.name or conv.output[0]}_unpadded"
    g.graph.initializer.append(
        numpy_helper.from_array(np.ascontiguousarray(w[:, :real]), f"{tag}.weight")
    )
    nodes = [
        helper.make_node("Concat", list(concat.input[:-1]), [f"{tag}_cat"], axis=1),
        helper.make_node("Conv", [f"{tag}_cat", f"{tag}.weight", conv.input[2]], [f"{tag}_conv"]),
    ]
    nodes[1].attribute.extend(conv.attribute)
    last = _activated(nodes, activation, f"{tag}_conv", tag)
    then_branch = _branch(f"{tag}_unpadded", nodes, last, g.values[moved[-1].output[0]])
    _replace_with_if(g, moved, then_branch, tag)
    return True


RULES: tuple[Callable[[_Graph, onnx.NodeProto], bool], ...] = (row_phases, zero_inputs_dropped)


def layout_forms(proto: onnx.ModelProto) -> list[str]:
    """Put each conv that has an AVX-512 form under If(layout.nchwc16) (module docstring);
    '<rule>: <conv>' per conv rewritten."""
    done = []
    for rule in RULES:
        for conv in [n for n in proto.graph.node if n.op_type == "Conv"]:
            g = _Graph(proto)
            if rule(g, conv):
                done.append(f"{rule.__name__}: {conv.name or conv.output[0]}")
    if done and LAYOUT_FLAG not in {i.name for i in proto.graph.initializer}:
        proto.graph.initializer.append(numpy_helper.from_array(np.array(False), LAYOUT_FLAG))
    return done
