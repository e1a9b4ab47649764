"""Run a narrow 'same' convolution as one stride-2 conv over its four output phases, at export.

ONNX Runtime's blocked (NCHWc) conv computes output channels in blocks of 8 and reuses each
loaded input vector across a block; a wide input with few outputs leaves the kernel starved.
NBG's GuideNet conv 24 -> 5 (5 x 5, sigmoid) ran at about 44 GFLOP/s at 720p on 2 cores,
against 80-110 for the 16-wide layers. Written over its four output phases it has 4x the
outputs at a quarter of the positions:

    y[:, c, 2i + py, 2j + px] = Conv(x, W_(py, px), b, stride 2)[:, 4c + 2py + px, i, j]

where W_(py, px) is the (K + 1) x (K + 1) kernel holding W at offset (py, px) and zeros
elsewhere (pads K//2 top/left, K//2 + 1 bottom/right). The four phases are one conv of 4 x C_out
outputs, phase-minor; a ConvTranspose (stride 2, 2 x 2, one group per output channel, one-hot
weights) interleaves them (5 ms at 720p where ORT's DepthToSpace took 28) and a Slice crops to
H x W (an odd size computes one extra row or column, then drops it). Each output is the same
products summed in the same order plus exact zeros: ONNX Runtime's outputs were bit-identical.
(Only non-finite values can differ: an inf in one phase becomes NaN in the three pixels next to
it, 0 x inf; the runtime keeps its inputs finite.) A unary activation that is the conv's only
reader moves before the interleave, where ORT still fuses it into the conv.

Where it pays (one-conv sessions at 720p, 2 cores, 2026-11-28, with DepthToSpace): K = 5 with
at most 5 outputs and at least 16 inputs, 0.6-0.8x (24 -> 5: 139 -> 95-108 ms; 32 -> 5: 182 ->
122; 16 -> 3: 93 -> 57); 3 x 3 kernels, 6 or more outputs, or fewer inputs measured no faster
or slower (10 -> 4 and 4 -> 3, 3 x 3: 1.5-1.9x). demo:nbg whole frame: benchmarks/README.md.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .conv_widths import Graph, auto_pad, ints_attribute, is_standard

MIN_KERNEL = 5  # 3 x 3 convs measured slower split
MAX_OUTPUTS = 5  # 4 x 5 = 20 phase outputs: three 8-wide blocks, 83% used
MIN_INPUTS = 16
# element-wise ops that commute with the interleave and the crop; ORT fuses these into a Conv
ACTIVATIONS = {"Relu", "LeakyRelu", "Sigmoid", "Tanh", "HardSigmoid", "Clip"}
# doc_string of a rewritten Conv: (K+1)^2 taps of which K^2 are the model's (benchmarks/flops.py)
PHASE_SPLIT_DOC = "rtdenoise: stride-2 conv over 4 output phases of a KxK conv, (K+1)^2 taps"


def _narrow_same_conv(g: Graph, conv: onnx.NodeProto) -> bool:
    """A plain square K x K conv (K odd >= MIN_KERNEL), stride and dilation 1, 'same' zero
    padding, with at most MAX_OUTPUTS outputs and at least MIN_INPUTS inputs."""
    if not g.plain_conv(conv) or conv.doc_string == PHASE_SPLIT_DOC:
        return False
    dims = list(g.inits[conv.input[1]].dims)
    if len(dims) != 4 or dims[2] != dims[3] or dims[2] % 2 == 0 or dims[2] < MIN_KERNEL:
        return False
    k = dims[2]
    return (
        dims[0] <= MAX_OUTPUTS
        and dims[1] >= MIN_INPUTS
        and auto_pad(conv) == b"NOTSET"
        and (ints_attribute(conv, "pads") or [0] * 4) == [k // 2] * 4
        and all(s == 1 for s in ints_attribute(conv, "strides") or [1])
        and all(d == 1 for d in ints_attribute(conv, "dilations") or [1])
    )


def phase_weights(weight: np.ndarray) -> np.ndarray:
    """(C_out, C_in, K, K) -> (4 C_out, C_in, K + 1, K + 1): output channel c's phase
    (py, px) at channel 4 c + 2 py + px, W shifted by (py, px)."""
    c_out, c_in, k, _ = weight.shape
    phases = np.zeros((c_out, 2, 2, c_in, k + 1, k + 1), weight.dtype)
    for py in range(2):
        for px in range(2):
            phases[:, py, px, :, py : py + k, px : px + k] = weight
    return phases.reshape(4 * c_out, c_in, k + 1, k + 1)


def interleave_weights(c_out: int, dtype: np.dtype) -> np.ndarray:
    """ConvTranspose weights (4 C_out, 1, 2, 2), group C_out: channel 4 c + 2 py + px to output
    channel c at offset (py, px)."""
    one_hot = np.zeros((c_out, 2, 2, 1, 2, 2), dtype)
    for py in range(2):
        for px in range(2):
            one_hot[:, py, px, 0, py, px] = 1
    return one_hot.reshape(4 * c_out, 1, 2, 2)


def phase_split_convs(proto: onnx.ModelProto) -> list[str]:
    """Rewrite, in place, every narrow 'same' conv of the main graph (`_narrow_same_conv`) as
    the phase conv + interleave + Slice of the module docstring; returns their names."""
    g = Graph(proto)
    graph = proto.graph
    done = []
    for conv in list(graph.node):
        if not _narrow_same_conv(g, conv):
            continue
        weight_init = g.inits[conv.input[1]]
        weight = numpy_helper.to_array(weight_init)
        c_out, k = weight.shape[0], weight.shape[2]
        weight_init.CopyFrom(numpy_helper.from_array(phase_weights(weight), weight_init.name))
        if len(conv.input) > 2 and conv.input[2]:
            bias_init = g.inits[conv.input[2]]
            bias = numpy_helper.to_array(bias_init)
            bias_init.CopyFrom(numpy_helper.from_array(np.repeat(bias, 4), bias_init.name))
        kept = [a for a in conv.attribute if a.name not in ("kernel_shape", "pads", "strides")]
        del conv.attribute[:]
        conv.attribute.extend(kept)
        p = k // 2
        conv.attribute.extend(
            [
                helper.make_attribute("kernel_shape", [k + 1, k + 1]),
                helper.make_attribute("pads", [p, p, p + 1, p + 1]),
                helper.make_attribute("strides", [2, 2]),
            ]
        )
        conv.doc_string = PHASE_SPLIT_DOC
        readers = g.consumers[conv.output[0]]
        last = conv
        if (
            len(readers) == 1
            and readers[0].op_type in ACTIVATIONS
            and is_standard(readers[0])
            and readers[0].input[0] == conv.output[0]
            and conv.output[0] not in g.outputs
        ):
            last = readers[0]
        result = last.output[0]  # its name stays: the readers and graph outputs keep it
        base = conv.name or conv.output[0]
        phased, full, size = f"{result}_phases", f"{result}_interleaved", f"{base}_size"
        last.output[0] = phased
        starts, axes = f"{base}_crop_starts", f"{base}_crop_axes"
        one_hot = f"{base}_interleave_weight"
        graph.initializer.extend(
            [
                numpy_helper.from_array(interleave_weights(c_out, weight.dtype), one_hot),
                numpy_helper.from_array(np.zeros(2, np.int64), starts),
                numpy_helper.from_array(np.array([2, 3], np.int64), axes),
            ]
        )
        nodes = [
            helper.make_node("ConvTranspose", [phased, one_hot], [full], group=c_out,
                             kernel_shape=[2, 2], strides=[2, 2], name=f"{base}_interleave"),
            helper.make_node("Shape", [conv.input[0]], [size], start=2, end=4,
                             name=f"{base}_shape"),
            helper.make_node("Slice", [full, starts, size, axes], [result], name=f"{base}_crop"),
        ]  # fmt: skip
        at = list(graph.node).index(last) + 1
        following = list(graph.node)
        following[at:at] = nodes
        del graph.node[:]
        graph.node.extend(following)
        g.forget_shapes({conv.output[0], *conv.input[1:]})  # the exporter records weights, too
        done.append(conv.name)
        g = Graph(proto)
    return done
