"""torch -> ONNX under the contract v1 (design.md s.3, s.5).

The model (training form) is folded to deploy form, wrapped so that its dict
interface becomes the contract's positional inputs/outputs, exported with the
dynamo exporter (filter stages become `rtdenoise` custom nodes through the
custom translation table), given the model-local function bodies, the pinned
IR/opset versions and the contract metadata, and checked.
"""

from __future__ import annotations

import json
import logging
import warnings

import onnx
import torch
from torch import nn
from torch.export import Dim

from rtdenoise.models.base import BUFFER_CHANNELS, DenoiserModel

from . import ops as onnx_ops
from .deploy import to_deploy

CONTRACT_VERSION = "1"
IR_VERSION = 10
OPSET = 18


class ContractModule(nn.Module):
    """Positional view of a model: (buffers..., reset, state...) -> (output, state_next...)."""

    def __init__(self, model: DenoiserModel) -> None:
        super().__init__()
        self.model = model
        self.buffer_names = tuple(model.inputs)
        self.state_names = tuple(s.name for s in model.state_specs)

    def forward(self, *args: torch.Tensor) -> tuple[torch.Tensor, ...]:
        nb = len(self.buffer_names)
        buffers = dict(zip(self.buffer_names, args[:nb], strict=True))
        reset = args[nb]
        state = dict(zip(self.state_names, args[nb + 1 :], strict=True))
        output, next_state = self.model(buffers, state, reset)
        return (output, *(next_state[name] for name in self.state_names))

    def input_names(self) -> list[str]:
        return [*self.buffer_names, "reset", *(f"state.{n}" for n in self.state_names)]

    def output_names(self) -> list[str]:
        return ["output", *(f"state_next.{n}" for n in self.state_names)]


def example_size(pad_multiple: int) -> tuple[int, int]:
    """A trace size: multiples of pad_multiple, H != W, big enough for every pooling level."""
    h = pad_multiple * max(3, -(-48 // pad_multiple))
    return h, h + pad_multiple


def example_inputs(model: DenoiserModel, h: int, w: int) -> tuple[torch.Tensor, ...]:
    gen = torch.Generator().manual_seed(0)
    buffers = [torch.rand(1, BUFFER_CHANNELS[name], h, w, generator=gen) for name in model.inputs]
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
    buffers = [{2: scaled(hb, pad), 3: scaled(wb, pad)} for _ in model.inputs]
    state = [
        {2: scaled(hb, pad // s.scale), 3: scaled(wb, pad // s.scale)} for s in model.state_specs
    ]
    return (*buffers, None, *state)


def export_model(model: DenoiserModel) -> onnx.ModelProto:
    """Export a DenoiserModel (training or deploy form) to ONNX under contract v1."""
    deployed = to_deploy(model)
    wrapper = ContractModule(deployed).eval()
    h, w = example_size(deployed.pad_multiple)
    args = example_inputs(deployed, h, w)
    # The exporter's chatter (torchvision absent, axis renames, deprecations) is not the user's.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    with torch.no_grad(), onnx_ops.exporting(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.onnx.export(
            wrapper,
            args,
            dynamo=True,
            opset_version=OPSET,
            input_names=wrapper.input_names(),
            output_names=wrapper.output_names(),
            dynamic_shapes=(_dynamic_shapes(deployed),),  # one entry: the *args tuple
            custom_translation_table=onnx_ops.custom_translation_table(),
            optimize=True,
            verbose=False,
        )
    proto = program.model_proto
    onnx_ops.attach_functions(proto)
    proto.ir_version = IR_VERSION
    _set_metadata(proto, deployed)
    onnx.checker.check_model(proto, full_check=True)
    return proto


def _set_metadata(proto: onnx.ModelProto, model: DenoiserModel) -> None:
    meta = {
        "rtdenoise.contract": CONTRACT_VERSION,
        "rtdenoise.family": model.family,
        "rtdenoise.config": json.dumps(model.config(), sort_keys=True),
        "rtdenoise.inputs": json.dumps(
            {"buffers": list(model.inputs), "note": getattr(model, "input_note", "")}
        ),
        "rtdenoise.state": json.dumps(
            [{"name": s.name, "channels": s.channels, "scale": s.scale} for s in model.state_specs]
        ),
        "rtdenoise.pad_multiple": str(model.pad_multiple),
    }
    del proto.metadata_props[:]
    for key, value in meta.items():
        proto.metadata_props.add(key=key, value=value)
