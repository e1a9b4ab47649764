"""torch -> ONNX: `to_onnx` for any module, `export_model` for a denoiser under the contract.

`to_onnx` is the one torch -> ONNX step: the dynamo exporter with the custom translation
table (filter stages become `rtdenoise` custom nodes), the model-local function bodies
attached, the pinned IR/opset versions. `export_model` folds a denoiser to deploy form, wraps
its dict interface into the contract's positional inputs/outputs (names from its
`Declaration`, rtdenoise.runtime.contract), exports it with `to_onnx`, puts an online model's
update under an `If` (learning_branch.py), writes the contract metadata and runs the full
checker (docs/contract.md).
"""

from __future__ import annotations

import logging
import warnings
from typing import Any

import onnx
import torch
from torch import nn
from torch.export import Dim

from rtdenoise.models.base import BUFFER_CHANNELS, DenoiserModel, option_buffer
from rtdenoise.models.ops import exporting
from rtdenoise.runtime.contract import SAMPLES, Declaration
from rtdenoise.runtime.sequences.samples import feature_channels, sample_features_of

from . import ops as onnx_ops
from .conv_widths import pad_conv_inputs, pad_conv_widths
from .deploy import to_deploy
from .layout_forms import layout_forms
from .learning_branch import branch_learning
from .matmul_heads import matmul_heads
from .ops import IR_VERSION, OPSET
from .phase_split import phase_split_convs
from .pool_offsets import pool_index_offsets
from .pow_as_exp import pow_as_exp
from .relu_backward import relu_backward_as_mul
from .scatter_pad import slice_scatter_as_pad


def to_onnx(
    module: nn.Module, args: tuple, dynamic_shapes: Any = None, **kwargs: Any
) -> onnx.ModelProto:
    """Export `module(*args)` with the rtdenoise custom nodes and their function bodies.

    Extra keyword arguments go to torch.onnx.export (e.g. input_names, output_names).
    """
    options = {
        "dynamo": True,
        "opset_version": OPSET,
        "custom_translation_table": onnx_ops.custom_translation_table(),
        "optimize": True,
        "verbose": False,
    } | kwargs
    # The exporter's chatter (torchvision absent, axis renames, deprecations) is not the user's.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with torch.no_grad(), exporting(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(module, args, dynamic_shapes=dynamic_shapes, **options)
    proto = onnx_ops.attach_functions(program.model_proto)
    proto.ir_version = IR_VERSION
    strip_node_metadata(proto)
    return proto


def strip_node_metadata(proto: onnx.ModelProto) -> None:
    """Drop the exporter's per-node metadata (stack traces with the exporting machine's paths,
    FX node dumps): a fifth to two thirds of a shipped file, and nothing a runtime reads."""
    graphs = [proto.graph]
    while graphs:
        graph = graphs.pop()
        for node in graph.node:
            del node.metadata_props[:]
            graphs.extend(a.g for a in node.attribute if a.type == onnx.AttributeProto.GRAPH)
            for a in node.attribute:
                graphs.extend(a.graphs)
    for function in proto.functions:
        for node in function.node:
            del node.metadata_props[:]


class ContractModule(nn.Module):
    """Positional view of a model: (buffers..., reset, state...) -> (output, state_next...)."""

    def __init__(self, model: DenoiserModel) -> None:
        super().__init__()
        self.model = model
        self.declared: Declaration = model.declaration()
        self.state_names = tuple(s.name for s in self.declared.state)

    def forward(self, *args: torch.Tensor) -> tuple[torch.Tensor, ...]:
        nb = len(self.declared.buffers)
        buffers = dict(zip(self.declared.buffers, args[:nb], strict=True))
        reset = args[nb]
        state = dict(zip(self.state_names, args[nb + 1 :], strict=True))
        output, next_state = self.model(buffers, state, reset)
        return (output, *(next_state[name] for name in self.state_names))


def example_size(pad_multiple: int) -> tuple[int, int]:
    """A trace size: multiples of pad_multiple, H != W, big enough for every pooling level."""
    h = pad_multiple * max(3, -(-48 // pad_multiple))
    return h, h + pad_multiple


EXAMPLE_SAMPLES = 2  # S of the traced `samples` buffer (S is a dynamic dim of the export)


def example_buffer(model: DenoiserModel, name: str, h: int, w: int, gen=None) -> torch.Tensor:
    """A random (1, C, H, W) buffer, or (1, S, C, H, W) for `samples` (C from the config)."""
    if name == SAMPLES:
        c = feature_channels(sample_features_of(model.config()))
        return torch.rand(1, EXAMPLE_SAMPLES, c, h, w, generator=gen)
    return torch.rand(1, BUFFER_CHANNELS[name], h, w, generator=gen)


def example_inputs(model: DenoiserModel, h: int, w: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(0)
    buffers = [example_buffer(model, name, h, w, gen) for name in model.inputs]
    state = model.initial_state(1, h, w)
    return (*buffers, torch.tensor(1.0), *(state[s.name] for s in model.state_specs))


def _dynamic_shapes(model: DenoiserModel) -> tuple:
    pad = model.pad_multiple
    hb, wb = Dim("hb", min=2, max=2048), Dim("wb", min=2, max=2048)

    def scaled(block: Dim, factor: int):
        return block if factor == 1 else factor * block

    for spec in model.state_specs:
        if pad % spec.scale:
            raise ValueError(
                f"state {spec.name!r}: scale {spec.scale} does not divide pad_multiple {pad}"
            )
    samples = Dim("samples", min=1, max=1024)
    buffers = [
        {1: samples, 3: scaled(hb, pad), 4: scaled(wb, pad)}
        if name == SAMPLES
        else {2: scaled(hb, pad), 3: scaled(wb, pad)}
        for name in model.inputs
    ]
    state = [
        None if s.size else {2: scaled(hb, pad // s.scale), 3: scaled(wb, pad // s.scale)}
        for s in model.state_specs
    ]
    return (*buffers, None, *state)


def expose_options(proto: onnx.ModelProto, declared: Declaration) -> None:
    """Make each declared run-time option (the model buffer `option_<name>`, an initializer
    of the export) the overridable initializer `option.<name>`: renamed, and a graph input."""
    graph = proto.graph
    for option in declared.options:
        old = f"model.{option_buffer(option.name)}"
        found = [t for t in graph.initializer if t.name == old]
        if not found:
            raise ValueError(
                f"run-time option {option.name!r}: the export has no initializer {old!r} (the "
                f"model must pass its buffer {option_buffer(option.name)} to the graph unchanged)"
            )
        found[0].name = option.input_name
        for node in graph.node:
            node.input[:] = [option.input_name if i == old else i for i in node.input]
        graph.input.append(
            onnx.helper.make_tensor_value_info(option.input_name, onnx.TensorProto.FLOAT, [])
        )


def export_model(model: DenoiserModel) -> onnx.ModelProto:
    """Export a DenoiserModel (training or deploy form) to ONNX under contract v1."""
    deployed = to_deploy(model)
    wrapper = ContractModule(deployed).eval()
    h, w = example_size(deployed.pad_multiple)
    args = example_inputs(deployed, h, w)
    proto = to_onnx(
        deployed.export_module(wrapper, args),  # the family may trace it first (base.py)
        args,
        dynamic_shapes=(_dynamic_shapes(deployed),),  # one entry: the *args tuple
        input_names=wrapper.declared.input_names(),
        output_names=wrapper.declared.output_names(),
    )
    pad_conv_widths(proto)  # same function; ORT's blocked conv layout (conv_widths.py)
    pad_conv_inputs(proto)
    phase_split_convs(proto)  # a narrow K x K conv over its 4 output phases (phase_split.py)
    matmul_heads(proto)  # a head split by Slices as MatMuls (matmul_heads.py)
    pow_as_exp(proto)  # x ** c as exp(c log x): ORT's Pow is scalar (pow_as_exp.py)
    pool_index_offsets(proto)  # a pool's index offsets from the shape (pool_offsets.py)
    slice_scatter_as_pad(proto)  # a slice_scatter into zeros as a Pad (scatter_pad.py)
    relu_backward_as_mul(proto)  # a ReLU's backward Where as a multiply (relu_backward.py)
    expose_options(proto, wrapper.declared)
    # an online model's backward pass and optimiser step under an If: frozen frames skip them
    branch_learning(proto, wrapper.declared.online)
    layout_forms(proto)  # AVX-512 conv forms under If(layout.nchwc16) (layout_forms.py)
    del proto.metadata_props[:]
    for key, value in wrapper.declared.metadata().items():
        proto.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(proto, full_check=True)
    return proto
