"""`OpSpec`: the one declaration of a custom op that its three forms derive from.

A filter stage of a denoiser is one op of the ONNX domain `rtdenoise` (version 1). It is
declared once, here in `rtdenoise.ops`, free of torch and onnx (numpy only), and implemented
three times, each form found by the op's name (docs/architecture.md, "The three forms"):

- torch (`rtdenoise.models.ops.<op>`): differentiable reference; `torch_op` builds the
  `torch.library` custom op, its fake, the argument checks and the export switch from the spec;
- ONNX (`rtdenoise.export.ops.<op>`): a function body in standard ops; `function_body` builds
  the OpSchema, the exporter translation and the model-local FunctionProto from the spec;
- fast kernel (`rtdenoise.runtime.kernels.<op>`): a numba kernel; `fast_kernel` converts the
  inputs, checks them, allocates the outputs and registers it with ONNX Runtime.

Shapes are tuples of ints (or of torch SymInts inside `register_fake`: the shape rules use
only arithmetic, so they work on both).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

DOMAIN = "rtdenoise"
DOMAIN_VERSION = 1

Shape = tuple  # of int (or SymInt)
Attrs = Mapping[str, int]
ShapeRule = Callable[[Sequence[Shape], Attrs], list[Shape]]
Check = Callable[[Sequence[Shape], Attrs], None]
T = TypeVar("T")
ExampleInputs = Callable[[tuple[int, int, int, int], Attrs, np.random.Generator], list[np.ndarray]]


@dataclass(frozen=True)
class Arg:
    """A tensor input or output: its name and rank (all float32)."""

    name: str
    rank: int = 4


def _no_check(shapes: Sequence[Shape], attrs: Attrs) -> None:
    return None


def snake_case(name: str) -> str:
    """'KernelApply' -> 'kernel_apply' (the torch.ops.rtdenoise name of an op)."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


@dataclass(frozen=True)
class OpSpec:
    """One custom op: what every form reads.

    name: ONNX op_type (CamelCase); `torch_name` is its snake_case form.
    doc: the definition in one paragraph, citing the paper's equation.
    inputs / outputs: float32 tensors in call order.
    attrs: int attributes, all required on every node (ONNX Runtime extension ops take no
        list or float attributes: precise floats travel as tensor inputs).
    output_shapes(input_shapes, attrs): the output shapes (also used by `register_fake`).
    check(input_shapes, attrs): raise ValueError, naming the problem, for an invalid call
        (ranks and the number of inputs and attributes are checked before it).
    example_inputs(image_shape, attrs, rng): valid float32 inputs for an (N, C, H, W) image,
        for the three-form tests and the stage benchmark.
    default_attrs: typical attribute values (benchmarks); example_attrs and example_shapes:
        the attribute sets and image shapes the generic three-form test runs.
    optional_attrs: attributes added after models were exported and shipped without them,
        with the value a node or call that omits one takes (the old behaviour): every form
        and bridge fills them in (`with_optional`), so an old .onnx file keeps running; the
        exporter still writes every attribute.
    """

    name: str
    doc: str
    inputs: tuple[Arg, ...]
    outputs: tuple[Arg, ...]
    output_shapes: ShapeRule
    example_inputs: ExampleInputs
    attrs: tuple[str, ...] = ()
    check: Check = _no_check
    default_attrs: Mapping[str, int] = field(default_factory=dict)
    example_attrs: tuple[Mapping[str, int], ...] = ()
    example_shapes: tuple[tuple[int, int, int, int], ...] = ((1, 3, 13, 17), (2, 1, 8, 6))
    optional_attrs: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if set(self.default_attrs) != set(self.attrs):
            raise ValueError(f"{self.name}: default_attrs must give every attribute {self.attrs}")
        if not set(self.optional_attrs) <= set(self.attrs):
            raise ValueError(f"{self.name}: optional_attrs must be attributes {self.attrs}")

    def with_optional(self, attrs: Mapping[str, int]) -> dict[str, int]:
        """`attrs` with every omitted optional attribute set to its value (`optional_attrs`)."""
        return {**self.optional_attrs, **attrs}

    @property
    def torch_name(self) -> str:
        return snake_case(self.name)

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.inputs)

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.outputs)

    def attr_sets(self) -> tuple[Mapping[str, int], ...]:
        """The attribute sets the three-form test runs: example_attrs, else the defaults."""
        return self.example_attrs or (dict(self.default_attrs),)

    def split_args(self, args: Sequence, attrs: Mapping[str, int]) -> tuple[list, dict[str, int]]:
        """(inputs, attributes) of a call `op(*args, **attrs)`: arguments after the inputs
        are attributes in spec order; omitted optional attributes take their values."""
        n = len(self.inputs)
        extra = dict(zip(self.attrs, args[n:], strict=False))
        if len(args) > n + len(self.attrs) or set(extra) & set(attrs):
            raise ValueError(f"{self.name}: too many arguments or an attribute given twice")
        values = self.with_optional({**extra, **attrs})
        return list(args[:n]), {k: int(v) for k, v in values.items()}

    def validate_call(self, shapes: Sequence[Shape], attrs: Attrs) -> None:
        """ValueError unless `shapes` and `attrs` are a valid call of this op (an omitted
        optional attribute takes its value)."""
        if len(shapes) != len(self.inputs):
            raise ValueError(f"{self.name} takes {len(self.inputs)} inputs, got {len(shapes)}")
        attrs = self.with_optional(attrs)
        if set(attrs) != set(self.attrs):
            raise ValueError(
                f"{self.name} takes attributes {list(self.attrs)}, got {sorted(attrs)}"
            )
        for arg, shape in zip(self.inputs, shapes, strict=True):
            if len(shape) != arg.rank:
                raise ValueError(
                    f"{self.name}: {arg.name} must be {arg.rank}-D, got shape {tuple(shape)}"
                )
        self.check(shapes, attrs)


def form_decorator(
    table: dict[str, T], kind: str, build: Callable[[OpSpec, Callable], T]
) -> Callable[[OpSpec | str], Callable[[Callable], T]]:
    """A decorator factory `deco(spec_or_name)(fn)` that builds one form of an op from its spec
    and `fn` with `build(spec, fn)` and records it in `table` under the op's name (one `kind`
    of form per op). `torch_op`, `function_body` and `fast_kernel` are made with it."""

    def decorator(spec: OpSpec | str) -> Callable[[Callable], T]:
        if isinstance(spec, str):
            from . import get_spec  # the registry of specs, filled when the package loads

            spec = get_spec(spec)

        def wrap(fn: Callable) -> T:
            if spec.name in table:
                raise ValueError(f"{spec.name} has two {kind}s")
            table[spec.name] = form = build(spec, fn)
            return form

        return wrap

    return decorator


def same_nhw(op: str, shapes: Sequence[Shape], names: Sequence[str]) -> None:
    """ValueError unless every (N, C, H, W) shape has the first one's N, H and W."""
    n, _, h, w = shapes[0]
    for name, shape in zip(names[1:], shapes[1:], strict=True):
        if (shape[0], shape[2], shape[3]) != (n, h, w):
            raise ValueError(
                f"{op}: {name} has shape {tuple(shape)}; expected N, H, W = {n}, {h}, {w} "
                f"like {names[0]}"
            )


def example_geometry(
    shape: Shape, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Example G-buffers of the reprojecting ops: smooth depth in [1.1, 1.9] (n, 1, h, w),
    unit normals tilted smoothly (n, 3, h, w), float32, and `agree` (n, 1, h, w) bool, True on
    about 3/4 of the pixels: where the example's previous geometry equals the current one."""
    n, _c, h, w = shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    phase = rng.uniform(0, 2 * np.pi, (n, 1, 1, 1))
    depth = (1.5 + 0.4 * np.sin(xs / 5.0 + ys / 7.0 + phase)).astype(np.float32)
    tilt = 0.2 * np.sin(xs / 6.0 - ys / 4.0 + phase)
    normal = np.concatenate([tilt, 0.5 * tilt, np.ones_like(tilt)], axis=1)
    normal = (normal / np.linalg.norm(normal, axis=1, keepdims=True)).astype(np.float32)
    return depth, normal, rng.random((n, 1, h, w)) < 0.75
