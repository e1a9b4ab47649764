"""The ONNX Runtime session a `Denoiser` drives: model source, execution providers, session
options, threads, the CPU arena and the fast-kernel bridge (docs/architecture.md, "Runtime").

`open_session` makes the options (threads, spinning, thread placement, a shared arena), registers
the fast kernels through the bridge asked for (`rtdenoise.runtime.bridge`; the portable bodies,
with one warning, where neither the C++ library nor numba can run them), loads the model and
checks that every provider asked for started. `kernel_thread_count` is the rule for the fast
kernels' threads on a frame size.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import onnxruntime as ort

from .contract import Contract, ContractError
from .errors import InputError
from .external_data import check_external_data
from .layout import has_layout_flag, nchwc_block, with_layout
from .memory import share_cpu_arena
from .placement import INTRA_OP_AFFINITIES, allowed_cpus, ort_thread_affinities
from .static_check import check_custom_nodes, custom_op_types, fill_optional_attributes

ModelSource = str | os.PathLike | bytes
Provider = str | tuple[str, dict[str, Any]]

_PROVIDER_ALIASES = {
    "cpu": "CPUExecutionProvider",
    "cuda": "CUDAExecutionProvider",
    "tensorrt": "TensorrtExecutionProvider",
    "trt": "TensorrtExecutionProvider",
    "dml": "DmlExecutionProvider",
    "directml": "DmlExecutionProvider",
    "coreml": "CoreMLExecutionProvider",
    "openvino": "OpenVINOExecutionProvider",
}
# Execution provider -> OrtValue device type used to keep the state on the device.
_DEVICE_OF_PROVIDER = {
    "CUDAExecutionProvider": "cuda",
    "TensorrtExecutionProvider": "cuda",
    "DmlExecutionProvider": "dml",
}
# The fast kernels run on one numba thread on frames below this many pixels (padded H x W):
# there numba's parallel regions (a wake-up and a barrier each; on a busy machine a scheduler
# time slice) cost more than they save (docs/architecture.md, "Threads").
SERIAL_KERNELS_BELOW = 256 * 256
ALLOW_SPINNING = "session.intra_op.allow_spinning"  # ORT session config key, "0" or "1"
# ORT session config key: where a model loaded from bytes finds its external data files.
EXTERNAL_DATA_FOLDER = "session.model_external_initializers_file_folder_path"
_portable_warned = False  # the portable bodies' warning was given (once per process)


def kernel_thread_count(
    padded: tuple[int, int], threads: int | None, serial_below: int = SERIAL_KERNELS_BELOW
) -> int | None:
    """numba threads for the fast kernels on frames of `padded` (H, W): one below
    `serial_below` pixels, else `threads` (None: numba's own setting)."""
    return 1 if padded[0] * padded[1] < serial_below else threads


def resolve_model(spec: str | os.PathLike) -> Path:
    """Path of a model given as `demo:<family>` (a shipped demo) or a plain .onnx path."""
    text = os.fspath(spec)
    if text.startswith("demo:"):
        from rtdenoise.shipped import demo_model

        try:
            return demo_model(text[len("demo:") :], ".onnx")
        except FileNotFoundError as exc:
            raise InputError(str(exc)) from None
    path = Path(text).expanduser()
    if not path.exists():
        raise InputError(f"{path}: no such model file")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected an .onnx model file")
    if path.suffix.lower() in (".pt", ".pth"):
        raise InputError(f"{path}: is a PyTorch checkpoint; export it first (denoise-export)")
    return path


class CheckedModel(NamedTuple):
    """A model that passed the checks: the name errors give it, what ONNX Runtime loads, the
    op types of its rtdenoise nodes (what a fast path must hold), and whether it holds layout
    forms (runtime/layout.py: then its bytes are rewritten at load)."""

    source: str
    payload: str | bytes
    ops: frozenset[str]
    layout_forms: bool


def checked_model(model: ModelSource) -> CheckedModel:
    """A model given as a path, `demo:<family>` or the serialized bytes, after the checks
    every file passes: its external data inside its folder, its custom ops' attributes
    consistent with the recorded shapes."""
    if isinstance(model, (bytes, bytearray)):
        source, payload = "<model bytes>", bytes(model)
        check_external_data(payload)
        check_custom_nodes(payload, source)
        return CheckedModel(source, payload, custom_op_types(payload), has_layout_flag(payload))
    path = resolve_model(model)
    data = path.read_bytes()  # read once for the checks
    check_external_data(path, data)  # every external data file inside the model's folder
    check_custom_nodes(data, str(path))  # attributes vs shapes
    return CheckedModel(str(path), str(path), custom_op_types(data), has_layout_flag(data))


def resolve_providers(providers: Sequence[Provider] | str | None) -> list[Provider]:
    """Execution providers for the session: aliases expanded, availability checked, CPU last."""
    if providers is None:
        return ["CPUExecutionProvider"]
    if isinstance(providers, str):
        providers = [providers]
    available = ort.get_available_providers()
    resolved: list[Provider] = []
    for item in providers:
        name, options = item if isinstance(item, tuple) else (item, None)
        name = _PROVIDER_ALIASES.get(name.lower(), name)
        if name not in available:
            raise InputError(
                f"execution provider {name!r} is not available in this onnxruntime "
                f"{ort.__version__} (available: {', '.join(available)}); CUDA/TensorRT need "
                "the onnxruntime-gpu package, DirectML onnxruntime-directml"
            )
        resolved.append((name, options) if options else name)
    if "CPUExecutionProvider" not in provider_names(resolved):
        resolved.append("CPUExecutionProvider")
    return resolved


def provider_names(providers: Sequence[Provider]) -> list[str]:
    """The names of `providers` (without their options)."""
    return [p if isinstance(p, str) else p[0] for p in providers]


def register_fast_kernels(
    options: ort.SessionOptions, bridge: str | None, ops: frozenset[str] | None = None
) -> str:
    """Register the fast kernels of the rtdenoise custom ops `ops` (the model's) through
    `bridge` (None: the best available for them); the bridge used. Where none can run them
    (no C++ library holding them all, and no numba or, for the extensions bridge, no
    onnxruntime-extensions) "": the portable bodies run, with one warning per process saying
    what to install; InputError naming the extra for a numba bridge asked for by name."""
    global _portable_warned
    from . import bridge as bridges

    try:
        return bridges.register_fast_kernels(options, bridge, ops)
    except ModuleNotFoundError as exc:
        missing = (exc.name or "").split(".")[0]
        if missing not in ("onnxruntime_extensions", "numba"):
            raise
        if bridge is not None:
            message = f"fast_kernels={bridge!r}: {exc}; pip install 'rtdenoise[numba]'"
            raise InputError(message) from None
        if not _portable_warned:
            _portable_warned = True
            warnings.warn(
                f"fast kernels unavailable: {exc}; the custom ops run their portable ONNX "
                "bodies, slower; pip install 'rtdenoise[numba]' (wheels for CPython 3.10-3.13 "
                "on Linux x86_64/aarch64, macOS arm64, Windows x64), or reinstall rtdenoise "
                "with a C++17 compiler for the C++ library",
                RuntimeWarning,
                stacklevel=4,
            )
        return ""
    except ValueError as exc:  # an unknown bridge name
        raise InputError(f"fast_kernels={bridge!r}: {exc}") from None


@dataclass
class Session:
    """A loaded session and how it runs: the bridge of its fast kernels ("" for none), its
    thread settings, whether it shares the process's CPU arena, where bound state lives."""

    session: ort.InferenceSession
    bridge: str
    threads: int | None
    pin_threads: bool
    shared_arena: bool
    device: tuple[str, int] | None  # None: host memory
    layout: str = ""  # the conv forms chosen (runtime/layout.py): "nchwc16", "plain", "" none


def open_session(
    payload: str | bytes,
    source: str,
    *,
    fast_kernels: bool | str,
    threads: int | None,
    pin_threads: bool | None,
    spinning: bool | None,
    providers: Sequence[Provider] | str | None,
    shared_arena: bool,
    ops: frozenset[str] | None = None,
    layout: str | None = None,
    layout_forms: bool = True,
) -> Session:
    """Load `payload` (a path or the model bytes; `source` names it in errors; `ops` its
    rtdenoise op types, which pick the fast path) with the options `Denoiser` documents."""
    options = ort.SessionOptions()
    # Warnings at load are about graph internals (e.g. run-time option initializers that
    # are graph inputs by design: "will not be treated as constant"); errors still show.
    options.log_severity_level = 3
    if threads is not None:
        if threads < 1:
            raise InputError(f"threads must be >= 1, got {threads}")
        options.intra_op_num_threads = threads
        affinities = ort_thread_affinities(threads, allowed_cpus()) if pin_threads else None
        if affinities:  # ORT places its workers itself only when it picks the count
            options.add_session_config_entry(INTRA_OP_AFFINITIES, affinities)
    bridge = ""
    if fast_kernels:
        bridge = register_fast_kernels(
            options, fast_kernels if isinstance(fast_kernels, str) else None, ops
        )
    if bridge == "extensions":  # it refuses a node that omits an optional attribute
        payload = _optional_attributes_written(payload, options)
    if spinning is None and bridge:
        spinning = False  # idle ORT workers would spin while a kernel needs the cores
    if spinning is not None:
        options.add_session_config_entry(ALLOW_SPINNING, "1" if spinning else "0")
    wanted = resolve_providers(providers)
    names = provider_names(wanted)
    payload, layout = _layout_chosen(payload, options, names, layout, layout_forms)
    shared = shared_arena and names == ["CPUExecutionProvider"] and share_cpu_arena(options)
    try:
        session = ort.InferenceSession(payload, options, providers=wanted)
    except Exception as exc:  # onnxruntime's pybind errors derive from Exception only
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{source}: ONNX Runtime cannot load the model: {first}") from exc
    got = session.get_providers()
    for name in names:
        if name not in got:
            raise InputError(
                f"{source}: execution provider {name} failed to start (see ONNX "
                f"Runtime's log); the session would run on {', '.join(got)}"
            )
    return Session(
        session=session,
        bridge=bridge,
        threads=threads,
        pin_threads=threads is None if pin_threads is None else pin_threads,
        shared_arena=shared,
        device=_state_device(session, got),
        layout=layout,
    )


def _layout_chosen(
    payload: str | bytes,
    options: ort.SessionOptions,
    providers: list[str],
    asked: str | None,
    forms: bool,
) -> tuple[str | bytes, str]:
    """`payload` with its `layout.nchwc16` flag written (runtime/layout.py): as `asked`
    ("nchwc16" or "plain"), or for None the AVX-512 conv forms where ORT's CPU convs use
    16-channel blocks and the CPU provider alone runs the model; and which form ("" for a
    model without the flag; `forms` False says so without reading it)."""
    if asked not in (None, "nchwc16", "plain"):
        raise InputError(f"layout={asked!r}: expected 'nchwc16', 'plain' or None (this CPU's)")
    if not forms:
        return payload, ""
    data = payload if isinstance(payload, bytes) else Path(payload).read_bytes()
    if not has_layout_flag(data):
        return payload, ""
    try:
        auto = providers == ["CPUExecutionProvider"] and nchwc_block() == 16
    except ValueError as exc:
        raise InputError(str(exc)) from None
    nchwc16 = auto if asked is None else asked == "nchwc16"
    written = _edited(payload, data, options, lambda d: with_layout(d, nchwc16))
    return written, ("nchwc16" if nchwc16 else "plain") if written is not payload else ""


def _optional_attributes_written(payload: str | bytes, options: ort.SessionOptions) -> str | bytes:
    """`payload`, or its bytes with the omitted optional attributes of its rtdenoise nodes
    written out (`static_check.fill_optional_attributes`)."""
    data = payload if isinstance(payload, bytes) else Path(payload).read_bytes()
    return _edited(payload, data, options, fill_optional_attributes)


def _edited(
    payload: str | bytes,
    data: bytes,
    options: ort.SessionOptions,
    edit: Callable[[bytes], bytes | None],
) -> str | bytes:
    """`payload` (a path or bytes; `data` its bytes) as `edit` rewrites them, or `payload`
    itself where `edit` changes nothing (None); the bytes of a file keep finding its external
    data beside it."""
    written = edit(data)
    if written is None:
        return payload
    if not isinstance(payload, bytes):
        options.add_session_config_entry(EXTERNAL_DATA_FOLDER, str(Path(payload).parent))
    return written


def _state_device(session: ort.InferenceSession, providers: list[str]) -> tuple[str, int] | None:
    """Where bound state lives: None for host memory, else (device type, device id)."""
    for name in providers:
        device = _DEVICE_OF_PROVIDER.get(name)
        if device is None:
            continue
        options = session.get_provider_options().get(name, {})
        device_id = int(options.get("device_id", 0) or 0)
        try:
            ort.OrtValue.ortvalue_from_numpy(np.zeros(1, np.float32), device, device_id)
        except Exception as exc:
            warnings.warn(
                f"cannot allocate state on {device}:{device_id} ({exc}); keeping it on host",
                RuntimeWarning,
                stacklevel=4,
            )
            return None
        return device, device_id
    return None


def option_values(
    session: ort.InferenceSession, contract: Contract, overrides: Mapping[str, float], source: str
) -> dict[str, tuple[np.ndarray, ort.OrtValue]]:
    """name -> (value as a float32 scalar, its OrtValue) for every overridden run-time option;
    InputError for an option the model lacks or a value it refuses."""
    known = {o.name: o for o in contract.options}
    inputs = {i.name for i in session.get_overridable_initializers()}
    values = {}
    for name, value in overrides.items():
        option = known.get(name)
        if option is None:
            raise InputError(
                f"{source}: model {contract.family!r} has no run-time option {name!r} "
                f"(options: {', '.join(known) or 'none'})"
            )
        if option.input_name not in inputs:
            raise ContractError(
                f"{source}: option {name!r} is declared but {option.input_name!r} is "
                "not an overridable initializer of the graph"
            )
        array = np.array(option.check(value), np.float32)
        values[name] = (array, ort.OrtValue.ortvalue_from_numpy(array))
    return values
