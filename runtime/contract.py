"""The ONNX contract, version 1: the one module the exporter writes with and the runtime reads
with (docs/contract.md).

A contract model has float32 inputs `color`, `albedo`, ... ([1, C, H, W]), a scalar
`reset`, one `state.<name>` per temporal tensor ([1, C, H/scale, W/scale]), and
outputs `output` ([1, 3, H, W]) plus `state_next.<name>` for every state input. Its
`metadata_props` say which buffers it reads, its state and its pad multiple.

- `BUFFER_CHANNELS`: the canonical frame buffers (the one table; `samples` is rank 5);
- `StateSpec`: one temporal tensor, as models declare it and the metadata lists it;
- `RuntimeOption`: a scalar a runtime may change per session (optional key `rtdenoise.options`,
  the overridable initializer `option.<name>`), e.g. a kernel size;
- edge margin (optional key `rtdenoise.edge_margin`): pixels of the frame's edge repeated on
  every side before the graph and cropped from its output, for a model whose convolutions
  smear what lies at the frame's edge (docs/contract.md, "Metadata", "Driving a model");
- `Declaration`: what a model declares (family, config, buffers, state, pad multiple, note):
  its `metadata()` is what the exporter writes, its graph input/output names the wrapper's;
- `parse_contract` / `contract_from_session`: check metadata + graph I/O, give a `Contract`
  (whose `declaration` is what the model declared); anything off raises a one-line
  `ContractError` naming the model and the problem.

Torch-free: models/, export/ and runtime/ all import it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .errors import InputError

CONTRACT_VERSION = 1
PREFIX = "rtdenoise."
KEY_CONTRACT = PREFIX + "contract"
KEY_FAMILY = PREFIX + "family"
KEY_CONFIG = PREFIX + "config"
KEY_INPUTS = PREFIX + "inputs"
KEY_STATE = PREFIX + "state"
KEY_PAD = PREFIX + "pad_multiple"
KEY_ONLINE = PREFIX + "online"
KEY_OPTIONS = PREFIX + "options"
KEY_MARGIN = PREFIX + "edge_margin"
MAX_EDGE_MARGIN = 256  # the largest `rtdenoise.edge_margin` read (and a config may set)
REQUIRED_KEYS = (KEY_CONTRACT, KEY_FAMILY, KEY_CONFIG, KEY_INPUTS, KEY_STATE, KEY_PAD)

RESET = "reset"
OUTPUT = "output"
STATE_IN = "state."
STATE_OUT = "state_next."
OPTION = "option."
FLOAT = "tensor(float)"

# The canonical per-pixel frame buffers, (C, H, W) each: name -> C.
BUFFER_CHANNELS: dict[str, int] = {
    "color": 3,  # linear HDR radiance, mean of the frame's samples
    "color_b": 3,  # an independent second estimate (Choi24)
    "albedo": 3,
    "normal": 3,  # in [-1, 1]
    "depth": 1,  # linear view depth
    "motion": 2,  # pixels, previous position = current + motion, x right, y down
}
# What the buffers mean to an augmentation (training crops, flips, brightness).
RADIANCE_BUFFERS = ("color", "color_b")  # scale with the exposure
SCREEN_XY_BUFFERS = ("motion", "normal")  # components 0, 1 are screen x, y: flip with the image
# Per-sample data, (S, C, H, W) with S and C model-defined (graph input [1, S, C, H, W]).
SAMPLES = "samples"
BUFFER_RANK: dict[str, int] = {name: 4 for name in BUFFER_CHANNELS} | {SAMPLES: 5}
# The largest float16: the range of radiance a buffer may hold (runtime/guard.py), and where a
# half-float output (an EXR, a caller's `out`) is clamped.
HALF_MAX = 65504.0

Dim = int | str | None


class ContractError(InputError):
    """The model does not obey the rtdenoise ONNX contract (one-line message)."""


@dataclass(frozen=True)
class TensorInfo:
    """A graph input or output as ONNX Runtime reports it (`NodeArg`)."""

    name: str
    shape: tuple[Dim, ...]
    type: str = FLOAT


@dataclass(frozen=True)
class StateSpec:
    """One temporal tensor: `channels` x (H / scale) x (W / scale), or `channels` x h x w for a
    state of fixed `size` (h, w) that does not follow the frame (e.g. the weights and optimiser
    moments of a model that learns while it runs)."""

    name: str
    channels: int
    scale: int = 1
    size: tuple[int, int] | None = None

    @property
    def input_name(self) -> str:
        return STATE_IN + self.name

    @property
    def output_name(self) -> str:
        return STATE_OUT + self.name

    def spatial(self, height: int, width: int) -> tuple[int, int]:
        """(H/scale, W/scale) for padded H, W; `size` for a fixed-size state."""
        if self.size is not None:
            return (int(self.size[0]), int(self.size[1]))
        return (height // self.scale, width // self.scale)

    def shape(self, height: int, width: int) -> tuple[int, int, int, int]:
        """[1, C, H/scale, W/scale] for padded H, W ([1, C, h, w] for a fixed `size`)."""
        return (1, self.channels, *self.spatial(height, width))

    def to_json(self) -> dict[str, Any]:
        """The metadata entry (`size` only when fixed)."""
        entry: dict[str, Any] = {"name": self.name, "channels": self.channels, "scale": self.scale}
        if self.size is not None:
            entry["size"] = [int(self.size[0]), int(self.size[1])]
        return entry


@dataclass(frozen=True)
class RuntimeOption:
    """A float32 scalar a model lets the runtime change per session, e.g. a kernel size.

    In the file it is the initializer `option.<name>` that is also a graph input (ONNX Runtime:
    an overridable initializer), so a host that does not know it runs the model with `default`.
    `odd`: the value must be an odd integer; `minimum` / `maximum`: its range.
    """

    name: str
    default: float
    doc: str = ""
    minimum: float | None = None
    maximum: float | None = None
    odd: bool = False

    @property
    def input_name(self) -> str:
        return OPTION + self.name

    def check(self, value: float) -> float:
        """`value` as a float; InputError naming the option unless the model accepts it."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"option {self.name!r} needs a number, got {value!r}") from None
        bad = v != v or (self.odd and (v != int(v) or int(v) % 2 == 0))
        bad = bad or (self.minimum is not None and v < self.minimum)
        bad = bad or (self.maximum is not None and v > self.maximum)
        if bad:
            lo = "-inf" if self.minimum is None else f"{self.minimum:g}"
            hi = "inf" if self.maximum is None else f"{self.maximum:g}"
            kind = "an odd integer" if self.odd else "a number"
            raise InputError(f"option {self.name!r} must be {kind} in [{lo}, {hi}], got {value!r}")
        return v

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "default": self.default,
            "doc": self.doc,
            "minimum": self.minimum,
            "maximum": self.maximum,
            "odd": self.odd,
        }


@dataclass(frozen=True)
class Declaration:
    """What a model declares under the contract; `metadata()` is what an export writes."""

    family: str
    config: Mapping[str, Any]
    buffers: tuple[str, ...]
    state: tuple[StateSpec, ...]
    pad_multiple: int
    note: str = ""
    online: Mapping[str, Any] | None = None  # `rtdenoise.online`: how the model learns
    options: tuple[RuntimeOption, ...] = ()
    edge_margin: int = 0  # `rtdenoise.edge_margin`: edge pixels repeated on every side

    def input_names(self) -> list[str]:
        """Graph inputs in order: buffers, `reset`, then `state.<name>`."""
        return [*self.buffers, RESET, *(s.input_name for s in self.state)]

    def output_names(self) -> list[str]:
        """Graph outputs in order: `output`, then `state_next.<name>`."""
        return [OUTPUT, *(s.output_name for s in self.state)]

    def metadata(self) -> dict[str, str]:
        """The `metadata_props` of an exported model (every required key)."""
        return {
            KEY_CONTRACT: str(CONTRACT_VERSION),
            KEY_FAMILY: self.family,
            KEY_CONFIG: json.dumps(dict(self.config), sort_keys=True),
            KEY_INPUTS: json.dumps({"buffers": list(self.buffers), "note": self.note}),
            KEY_STATE: json.dumps([s.to_json() for s in self.state]),
            KEY_PAD: str(self.pad_multiple),
        } | self._optional_metadata()

    def _optional_metadata(self) -> dict[str, str]:
        extra = {}
        if self.online:
            extra[KEY_ONLINE] = json.dumps(dict(self.online))
        if self.options:
            extra[KEY_OPTIONS] = json.dumps([o.to_json() for o in self.options])
        if self.edge_margin:
            extra[KEY_MARGIN] = str(self.edge_margin)
        return extra


@dataclass(frozen=True)
class BufferSpec:
    """One frame buffer the model reads: (C, H, W), or (S, C, H, W) for rank-5 `samples`."""

    name: str
    rank: int
    channels: int | None
    graph_shape: tuple[Dim, ...]

    @property
    def expected(self) -> str:
        """Human-readable expected shape, e.g. '(3, H, W)'."""
        c = "C" if self.channels is None else str(self.channels)
        return f"({c}, H, W)" if self.rank == 4 else f"(S, {c}, H, W)"


@dataclass(frozen=True)
class Contract:
    """What the executor needs to drive a contract model."""

    version: int
    family: str
    config: dict[str, Any]
    buffers: tuple[BufferSpec, ...]
    note: str
    state: tuple[StateSpec, ...]
    pad_multiple: int
    has_reset: bool
    output_shape: tuple[Dim, ...]
    online: dict[str, Any] | None = None  # parsed `rtdenoise.online` (docs/contract.md)
    metadata: dict[str, str] = field(default_factory=dict)
    options: tuple[RuntimeOption, ...] = ()
    edge_margin: int = 0  # edge pixels repeated on every side before the graph, then cropped

    @property
    def buffer_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.buffers)

    @property
    def static_size(self) -> tuple[int, int] | None:
        """(H, W) when the graph fixes them (a non-dynamic export), else None."""
        for spec in self.buffers:
            dims = spec.graph_shape[-2:]
            if all(isinstance(d, int) and d > 0 for d in dims):
                return int(dims[0]), int(dims[1])
        return None

    @property
    def declaration(self) -> Declaration:
        """What the model declared (the inverse of `Declaration.metadata`)."""
        return Declaration(
            self.family,
            self.config,
            self.buffer_names,
            self.state,
            self.pad_multiple,
            self.note,
            self.online,
            self.options,
            self.edge_margin,
        )


def _static(dim: Dim) -> int | None:
    return dim if isinstance(dim, int) and not isinstance(dim, bool) and dim > 0 else None


def _pos_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def parse_contract(
    metadata: Mapping[str, str],
    inputs: Sequence[TensorInfo],
    outputs: Sequence[TensorInfo],
    *,
    source: str = "model",
) -> Contract:
    """Validate metadata + graph I/O against contract v1; raise ContractError on any violation."""

    def fail(msg: str) -> ContractError:
        return ContractError(f"{source}: not an rtdenoise contract-v1 model: {msg}")

    missing = [k for k in REQUIRED_KEYS if k not in metadata]
    if missing:
        have = sorted(k for k in metadata if k.startswith(PREFIX))
        raise fail(f"metadata key {missing[0]!r} missing (has {have or 'no rtdenoise.* keys'})")
    version = metadata[KEY_CONTRACT].strip()
    if version != str(CONTRACT_VERSION):
        raise fail(f"{KEY_CONTRACT} is {version!r}, this runtime reads version {CONTRACT_VERSION}")
    family = metadata[KEY_FAMILY].strip()
    if not family:
        raise fail(f"{KEY_FAMILY} is empty")

    def load(key: str) -> Any:
        try:
            return json.loads(metadata[key])
        except json.JSONDecodeError as exc:
            raise fail(f"{key} is not valid JSON ({exc.msg} at char {exc.pos})") from None

    config = load(KEY_CONFIG)
    if not isinstance(config, dict):
        raise fail(f"{KEY_CONFIG} must be a JSON object, got {type(config).__name__}")
    spec_inputs = load(KEY_INPUTS)
    names = spec_inputs.get("buffers") if isinstance(spec_inputs, dict) else None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise fail(f'{KEY_INPUTS} must be {{"buffers": [names...], "note": "..."}}')
    if len(set(names)) != len(names):
        raise fail(f"{KEY_INPUTS} lists a buffer twice: {names}")
    note = spec_inputs.get("note", "")
    note = note if isinstance(note, str) else json.dumps(note)
    try:
        pad = int(metadata[KEY_PAD].strip())
    except ValueError:
        raise fail(f"{KEY_PAD} is {metadata[KEY_PAD]!r}, not an integer") from None
    if pad < 1:
        raise fail(f"{KEY_PAD} must be >= 1, got {pad}")
    state = _parse_state(load(KEY_STATE), pad, fail)
    margin = _parse_margin(metadata[KEY_MARGIN], fail) if KEY_MARGIN in metadata else 0
    options = _parse_options(load(KEY_OPTIONS), fail) if KEY_OPTIONS in metadata else ()

    graph_in = {t.name: t for t in inputs}
    graph_out = {t.name: t for t in outputs}
    for t in (*inputs, *outputs):
        if t.type != FLOAT:
            raise fail(f"graph tensor {t.name!r} has type {t.type}, the contract needs float32")

    buffers = []
    for name in names:
        if name not in BUFFER_RANK:
            raise fail(f"{KEY_INPUTS} names unknown buffer {name!r} (known: {list(BUFFER_RANK)})")
        if name not in graph_in:
            raise fail(f"buffer {name!r} is listed in {KEY_INPUTS} but is not a graph input")
        buffers.append(_buffer_spec(name, graph_in[name].shape, fail))

    state_names = {s.input_name for s in state}
    for name in graph_in:
        if name in names or name == RESET or name in state_names:
            continue
        if name.startswith(STATE_IN):
            raise fail(f"graph input {name!r} is not listed in {KEY_STATE}")
        raise fail(f"graph input {name!r} is neither a listed buffer, 'reset' nor a state input")
    for s in state:
        if s.input_name not in graph_in:
            raise fail(
                f"state {s.name!r} is listed in {KEY_STATE} but {s.input_name!r} is no input"
            )
        if s.output_name not in graph_out:
            raise fail(f"state input {s.input_name!r} has no matching output {s.output_name!r}")
        for t in (graph_in[s.input_name], graph_out[s.output_name]):
            _check_4d(t, s.channels, f"state {s.name!r} ({s.channels} channels)", fail)

    has_reset = RESET in graph_in
    if has_reset and len(graph_in[RESET].shape) != 0:
        raise fail(
            f"'reset' must be a rank-0 scalar, graph has shape {list(graph_in[RESET].shape)}"
        )
    if state and not has_reset:
        raise fail("the model has state but no 'reset' input")

    if OUTPUT not in graph_out:
        raise fail(f"no graph output 'output' (outputs: {list(graph_out)})")
    _check_4d(graph_out[OUTPUT], 3, "'output' (3 channels)", fail)
    for name in graph_out:
        if name == OUTPUT:
            continue
        if not name.startswith(STATE_OUT):
            raise fail(f"graph output {name!r} is neither 'output' nor a state_next.* output")
        if STATE_IN + name[len(STATE_OUT) :] not in state_names:
            raise fail(f"graph output {name!r} has no matching listed state input")

    return Contract(
        version=CONTRACT_VERSION,
        family=family,
        config=config,
        buffers=tuple(buffers),
        note=note,
        state=state,
        pad_multiple=pad,
        has_reset=has_reset,
        output_shape=tuple(graph_out[OUTPUT].shape),
        online=_parse_online(load(KEY_ONLINE), state, fail) if KEY_ONLINE in metadata else None,
        metadata=dict(metadata),
        options=options,
        edge_margin=margin,
    )


def _parse_margin(raw: str, fail) -> int:
    try:
        margin = int(raw.strip())
    except ValueError:
        raise fail(f"{KEY_MARGIN} is {raw!r}, not an integer") from None
    if not 0 <= margin <= MAX_EDGE_MARGIN:
        raise fail(f"{KEY_MARGIN} must be in 0..{MAX_EDGE_MARGIN}, got {margin}")
    return margin


def _parse_state(raw: Any, pad: int, fail) -> tuple[StateSpec, ...]:
    if not isinstance(raw, list):
        raise fail(f"{KEY_STATE} must be a JSON list of {{name, channels, scale}}")
    specs: list[StateSpec] = []
    for item in raw:
        if not isinstance(item, dict) or not isinstance(item.get("name"), str) or not item["name"]:
            raise fail(f"{KEY_STATE} entry {item!r} needs a non-empty 'name'")
        channels, scale = item.get("channels"), item.get("scale", 1)
        if not _pos_int(channels) or not _pos_int(scale):
            raise fail(f"state {item['name']!r}: channels and scale must be integers >= 1")
        if pad % scale:
            raise fail(f"{KEY_PAD} {pad} is not a multiple of state {item['name']!r} scale {scale}")
        size = item.get("size")
        if size is not None:
            if not isinstance(size, list) or len(size) != 2 or not all(map(_pos_int, size)):
                raise fail(f"state {item['name']!r}: size must be [h, w], integers >= 1")
            size = (size[0], size[1])
        specs.append(StateSpec(item["name"], channels, scale, size))
    if len({s.name for s in specs}) != len(specs):
        raise fail(f"{KEY_STATE} lists a state name twice")
    return tuple(specs)


def _parse_options(raw: Any, fail) -> tuple[RuntimeOption, ...]:
    if not isinstance(raw, list):
        raise fail(f"{KEY_OPTIONS} must be a JSON list of {{name, default, ...}}")
    options = []
    for item in raw:
        name = item.get("name") if isinstance(item, dict) else None
        if not isinstance(name, str) or not name:
            raise fail(f"{KEY_OPTIONS} entry {item!r} needs a non-empty 'name'")
        try:
            option = RuntimeOption(
                name=name,
                default=float(item["default"]),
                doc=str(item.get("doc", "")),
                minimum=None if item.get("minimum") is None else float(item["minimum"]),
                maximum=None if item.get("maximum") is None else float(item["maximum"]),
                odd=bool(item.get("odd", False)),
            )
        except (KeyError, TypeError, ValueError):
            raise fail(f"{KEY_OPTIONS} entry {name!r} needs a numeric 'default'") from None
        options.append(option)
    if len({o.name for o in options}) != len(options):
        raise fail(f"{KEY_OPTIONS} lists an option twice")
    return tuple(options)


def _parse_online(raw: Any, state: tuple[StateSpec, ...], fail) -> dict[str, Any]:
    """`rtdenoise.online`: a JSON object; its controls `freeze` (the state a host sets to 1 to
    skip a frame's update) and `keep` (1: a reset keeps the learning) must name listed
    single-value states, the learning states (`parameters`, `moments`, `step`) listed ones, and
    `statistics` (other learned states) listed states of size [1, 1]."""
    if not isinstance(raw, dict):
        raise fail(f"{KEY_ONLINE} must be a JSON object, got {type(raw).__name__}")
    names = {s.name: s for s in state}
    for key in ("freeze", "keep"):
        control = raw.get(key)
        if control is not None:
            spec = names.get(control)
            if spec is None or spec.channels != 1 or spec.size != (1, 1):
                raise fail(f"{KEY_ONLINE} {key} {control!r} is not a listed 1-value state")
    statistics = raw.get("statistics", [])
    if not isinstance(statistics, list) or any(
        not isinstance(n, str) or n not in names or names[n].size != (1, 1) for n in statistics
    ):
        raise fail(f"{KEY_ONLINE} statistics must list states of size [1, 1], got {statistics!r}")
    if raw.get("keep") is not None:
        learned = learning_states(raw)
        if not learned or any(name not in names for name in learned):
            raise fail(f"{KEY_ONLINE} keep needs listed parameters, moments and step states")
    return raw


def learning_states(online: dict[str, Any] | None) -> tuple[str, ...]:
    """The states an online model learns (weights, optimiser moments, step, and running
    `statistics` such as crossreg's gain curve): what a reset that keeps the learning (`keep` =
    1) carries over."""
    if not online:
        return ()
    moments = online.get("moments") or []
    statistics = online.get("statistics") or []
    names = [online.get("parameters"), *moments, online.get("step"), *statistics]
    return tuple(n for n in names if isinstance(n, str))


def _buffer_spec(name: str, shape: tuple[Dim, ...], fail) -> BufferSpec:
    rank = BUFFER_RANK[name]
    if len(shape) != rank:
        raise fail(f"buffer {name!r} has graph rank {len(shape)}, the contract needs {rank}")
    if _static(shape[0]) not in (None, 1):
        raise fail(f"buffer {name!r} has batch size {shape[0]}, the contract needs 1")
    canonical = BUFFER_CHANNELS.get(name)
    graph_c = _static(shape[rank - 3])
    if canonical is not None and graph_c is not None and graph_c != canonical:
        raise fail(f"buffer {name!r} has {graph_c} channels in the graph, canonical is {canonical}")
    return BufferSpec(name, rank, canonical if canonical is not None else graph_c, tuple(shape))


def _check_4d(t: TensorInfo, channels: int, what: str, fail) -> None:
    if len(t.shape) != 4:
        raise fail(f"{t.name!r} has rank {len(t.shape)}, {what} needs [1, C, H, W]")
    if _static(t.shape[0]) not in (None, 1):
        raise fail(f"{t.name!r} has batch size {t.shape[0]}, the contract needs 1")
    if _static(t.shape[1]) not in (None, channels):
        raise fail(f"{t.name!r} has {t.shape[1]} channels in the graph, {what}")


def contract_from_session(session: Any, *, source: str = "model") -> Contract:
    """Read the contract of an `onnxruntime.InferenceSession`."""

    def info(args) -> list[TensorInfo]:
        return [TensorInfo(a.name, tuple(a.shape or ()), a.type) for a in args]

    metadata = dict(session.get_modelmeta().custom_metadata_map)
    return parse_contract(
        metadata, info(session.get_inputs()), info(session.get_outputs()), source=source
    )
