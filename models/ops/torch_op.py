"""`torch_op`: the torch form of a custom op from its spec and one reference function.

    @torch_op(SPEC)
    def kernel_apply_reference(image, kernel, kernel_size: int, dilation: int): ...

gives a `TorchOp` that model code calls with the spec's inputs and attributes. Every call
checks its arguments against the spec (`OpSpec.validate_call`), then runs the differentiable
reference, or, while exporting (`export_mode.use_custom_op()`), the `torch.library` custom op
`torch.ops.rtdenoise.<torch_name>` that the exporter turns into one `rtdenoise.<Name>` node.
The custom op, its schema and its fake (output shapes from the spec) are built here, once
for every op. `observe_calls` lets the stage benchmark see each call (inputs, attributes,
time) without knowing the ops.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator

import torch

from rtdenoise.ops import DOMAIN, OpSpec
from rtdenoise.ops.spec import form_decorator

from .export_mode import use_custom_op

Observer = Callable[["TorchOp", tuple[torch.Tensor, ...], dict[str, int], float], None]

TORCH_OPS: dict[str, TorchOp] = {}
_observers: list[Observer] = []
_running = threading.local()  # depth of op calls in progress (observers see the outermost)


def _schema(spec: OpSpec) -> str:
    args = [f"Tensor {a.name}" for a in spec.inputs] + [f"int {a}" for a in spec.attrs]
    outs = ", ".join("Tensor" for _ in spec.outputs)
    return f"({', '.join(args)}) -> {outs if len(spec.outputs) == 1 else f'({outs})'}"


class TorchOp:
    """The torch form of one op: `op(*inputs, **attrs)` or `op(*inputs, *attrs)` (see the
    module docstring)."""

    def __init__(self, spec: OpSpec, reference: Callable[..., torch.Tensor]) -> None:
        self.spec = spec
        self.reference = reference
        n = len(spec.inputs)

        def run(*args):
            tensors, values = args[:n], dict(zip(spec.attrs, args[n:], strict=True))
            with torch.no_grad():
                out = reference(*tensors, **values)
            return (
                tuple(o.contiguous() for o in out) if isinstance(out, tuple) else out.contiguous()
            )

        def fake(*args):
            tensors, values = args[:n], dict(zip(spec.attrs, args[n:], strict=True))
            shapes = spec.output_shapes([tuple(t.shape) for t in tensors], values)
            outs = tuple(tensors[0].new_empty(s) for s in shapes)
            return outs if len(outs) > 1 else outs[0]

        self.custom = torch.library.custom_op(
            f"{DOMAIN}::{spec.torch_name}", run, mutates_args=(), schema=_schema(spec)
        )
        self.custom.register_fake(fake)

    @property
    def name(self) -> str:
        return self.spec.name

    def overload(self):
        """`torch.ops.rtdenoise.<torch_name>.default` (the key of the exporter's table)."""
        return getattr(getattr(torch.ops, DOMAIN), self.spec.torch_name).default

    def __call__(self, *args: torch.Tensor | int, **attrs: int):
        inputs, attrs = self.spec.split_args(args, attrs)
        self.spec.validate_call([tuple(x.shape) for x in inputs], attrs)
        t0 = time.perf_counter() if _observers else 0.0
        outer = getattr(_running, "depth", 0) == 0  # not inside another op's torch form
        _running.depth = getattr(_running, "depth", 0) + 1
        try:
            if use_custom_op():
                out = self.custom(*inputs, *(attrs[a] for a in self.spec.attrs))
            else:
                out = self.reference(*inputs, **attrs)
        finally:
            _running.depth -= 1
        if _observers and outer:
            ms = (time.perf_counter() - t0) * 1e3
            for observer in list(_observers):
                observer(self, inputs, attrs, ms)
        return out

    def __repr__(self) -> str:
        return f"TorchOp({self.spec.name})"


# Decorator: the reference function (inputs, then attributes as keywords) -> TorchOp.
torch_op = form_decorator(TORCH_OPS, "torch form", TorchOp)


@contextlib.contextmanager
def observe_calls(observer: Observer) -> Iterator[None]:
    """Call `observer(op, inputs, attrs, ms)` after every op call inside this block (the
    model's calls: an op that another op's torch form calls, e.g. Reproject inside
    TemporalAccumulation, is part of that op's time)."""
    _observers.append(observer)
    try:
        yield
    finally:
        _observers.remove(observer)
