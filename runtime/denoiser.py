"""The stateful executor: one ONNX Runtime session driving any contract-v1 model
(docs/architecture.md, "Runtime"; docs/contract.md).

Per frame: validate the buffers (names, shapes), pass them through the input guard
(`runtime/guard.py`: NaN/Inf replaced, ranges clamped, colour outliers removed, all counted),
replicate-pad H, W to the model's `pad_multiple`, run, feed `state_next.*` back as
`state.*`, crop the output (NaN/Inf in it replaced by 0 and counted). State is zero-filled
and `reset` = 1 on the first frame, after `reset()`, when the resolution changes, on a frame
whose guide buffers are missing (zero everywhere) and on the frame after it or after a
non-finite output (docs/reliability.md).

State lives in two ping-pong buffers per tensor bound through ONNX Runtime's IO
binding: frame t reads buffer A and writes buffer B, frame t+1 the reverse. With a
GPU execution provider the buffers are device memory, so state never crosses to the
host; on CPU they are numpy arrays the session reads and writes in place.

Buffers come planar, (C, H, W) (or batched, (1, C, H, W)), or interleaved as a renderer holds
them, (H, W, C) with an optional alpha channel that is ignored ((H, W) for one channel), in
float32 or float16; the output follows the layout of `color`, or fills the caller's `out`.

Fast kernels run as Python custom ops inside `session.run`; an exception there would abort
the process, so the run is wrapped in `fastops.raise_kernel_errors()` (the kernel's error is
raised after the run) and in `deferred_signals()` (Ctrl-C is raised after the run).
One frame at a time: `process` and `reset` hold a lock, so an instance shared by threads
serialises their calls (docs/reliability.md, "Threads").
"""

from __future__ import annotations

import importlib
import os
import threading
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from .contract import (
    OPTION,
    OUTPUT,
    RESET,
    BufferSpec,
    Contract,
    ContractError,
    StateSpec,
    contract_from_session,
)
from .errors import InputError
from .external_data import check_external_data
from .guard import GuardReport, GuardTotals, guard_buffers, replace_nonfinite
from .interrupts import deferred_signals
from .memory import share_cpu_arena
from .placement import INTRA_OP_AFFINITIES, allowed_cpus, ort_thread_affinities, placed

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
_RESET = {True: np.array(1.0, np.float32), False: np.array(0.0, np.float32)}
# The fast kernels run on one numba thread on frames below this many pixels (padded H x W):
# there numba's parallel regions (a wake-up and a barrier each; on a busy machine a scheduler
# time slice) cost more than they save (docs/architecture.md, "Threads").
SERIAL_KERNELS_BELOW = 256 * 256
ALLOW_SPINNING = "session.intra_op.allow_spinning"  # ORT session config key, "0" or "1"
HALF_MAX = 65504.0  # the largest float16: an `out` in half float is clamped to it


def kernel_threads(
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
    if "CPUExecutionProvider" not in [p if isinstance(p, str) else p[0] for p in resolved]:
        resolved.append("CPUExecutionProvider")
    return resolved


def _register_fast_kernels(options: ort.SessionOptions, bridge: str | None) -> tuple[Any, str]:
    """Register the numba kernels of the rtdenoise custom ops through `bridge` (None: the
    best available): (the `fastops` module, the bridge used), or (None, "") with a warning if
    absent."""
    try:
        fastops = importlib.import_module(".fastops", __package__)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.split(".")[-1] in ("fastops", "onnxruntime_extensions", "numba"):
            warnings.warn(
                f"fast kernels unavailable ({exc}): the custom ops run their portable ONNX "
                "bodies, slower; numba and onnxruntime-extensions have wheels for CPython "
                "3.10-3.13 on Linux x86_64/aarch64, macOS arm64 and Windows x64",
                RuntimeWarning,
                stacklevel=3,
            )
            return None, ""
        raise
    try:
        return fastops, fastops.register_fast_kernels(options, bridge)
    except ValueError as exc:  # an unknown bridge name
        raise InputError(f"fast_kernels={bridge!r}: {exc}") from None


def _count_nonfinite(a: np.ndarray) -> int:
    """Number of NaN/Inf values; one cheap pass (a sum) when there are none."""
    if a.dtype.kind != "f":
        return 0
    with np.errstate(over="ignore", invalid="ignore"):  # a finite sum may overflow: recount
        if np.isfinite(a.sum()):
            return 0
    return int(a.size - np.count_nonzero(np.isfinite(a)))


def _pad_edge(a: np.ndarray, hp: int, wp: int) -> np.ndarray:
    """Replicate-pad the last two axes of `a` to (hp, wp) (bottom and right); `a` if no pad."""
    h, w = a.shape[-2:]
    if (h, w) == (hp, wp):
        return a
    out = np.empty(a.shape[:-2] + (hp, wp), np.float32)
    out[..., :h, :w] = a
    out[..., :h, w:] = a[..., :, w - 1 : w]
    out[..., h:, :] = out[..., h - 1 : h, :]
    return out


def _is_interleaved(a: np.ndarray, channels: int | None, channels_last: bool | None) -> bool:
    """Whether `a` is (H, W, C), (H, W, C + 1) or, for C = 1, (H, W); planar wins a tie."""
    if channels is None or channels_last is False:
        return False
    fits = (a.ndim == 3 and a.shape[-1] in (channels, channels + 1)) or (
        a.ndim == 2 and channels == 1
    )
    if channels_last:
        return fits
    planar = a.ndim in (3, 4) and a.shape[-3] == channels
    return fits and not planar


def _output_view(out: np.ndarray, size: tuple[int, int], channels_last: bool | None) -> np.ndarray:
    """The (3, H, W) view of a caller's output array that `_store` fills; InputError if unfit."""
    h, w = size
    if not isinstance(out, np.ndarray) or out.dtype not in (np.float32, np.float16):
        kind = out.dtype if isinstance(out, np.ndarray) else type(out).__name__
        raise InputError(f"out must be a float32 or float16 numpy array, got {kind}")
    if out.shape[:2] == (h, w) and _is_interleaved(out, 3, channels_last):
        return out[..., :3].transpose(2, 0, 1)
    if out.shape == (3, h, w) and channels_last is not True:
        return out
    raise InputError(
        f"out has shape {out.shape}; expected (3, {h}, {w}), ({h}, {w}, 3) or ({h}, {w}, 4)"
    )


def _store(target: np.ndarray, planar: np.ndarray) -> None:
    """Write a (3, H, W) float32 frame into the caller's view, clamping to the half range."""
    if target.dtype == np.float16:
        np.clip(planar, -HALF_MAX, HALF_MAX, out=target, casting="same_kind")
    else:
        np.copyto(target, planar)


class _Slot:
    """One state tensor's storage: an OrtValue, with its host numpy array when on CPU."""

    def __init__(self, shape: tuple[int, ...], device: tuple[str, int] | None):
        zeros = np.zeros(shape, np.float32)
        if device is None:
            self.host: np.ndarray | None = zeros
            self.value = ort.OrtValue.ortvalue_from_numpy(zeros)  # shares `zeros`' memory
        else:
            self.host = None
            self.value = ort.OrtValue.ortvalue_from_numpy(zeros, device[0], device[1])
        self.shape = shape

    def zero(self) -> None:
        if self.host is not None:
            self.host.fill(0.0)
        else:
            self.value.update_inplace(np.zeros(self.shape, np.float32))

    def sanitize(self) -> int:
        """Replace NaN/Inf by 0 in place; return how many there were."""
        host = self.host if self.host is not None else self.value.numpy()
        bad = _count_nonfinite(host)
        if bad:
            np.nan_to_num(host, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            if self.host is None:
                self.value.update_inplace(host)
        return bad


class Denoiser:
    """Run a contract-v1 ONNX denoiser frame by frame, keeping its temporal state.

    model: a path to an .onnx file, `demo:<family>`, or the serialized model bytes.
    fast_kernels: register the native (numba) kernels of the rtdenoise custom ops; False runs
        their portable ONNX function bodies, inlined by ONNX Runtime. A string picks how ONNX
        Runtime reaches the kernels: "native" (the compiled bridge, zero-copy; what True uses
        where it was built) or "extensions" (onnxruntime-extensions, which copies every input
        and output); `bridge` says which one runs.
    threads: threads of ONNX Runtime's intra-op pool and of the fast (numba) kernels, which
        run between its ops (None: each library's default, all cores). The kernels use one
        thread on frames below `serial_below` pixels (padded; default SERIAL_KERNELS_BELOW).
    pin_threads: during each run, keep the calling thread on its first allowed CPU and the
        kernels' workers on the others (Linux; the caller's affinity is restored after each
        frame): after an idle gap between frames the scheduler otherwise often stacks them on
        one core (`rtdenoise.runtime.placement`). None (default): when `threads` is None, where
        ONNX Runtime pins its own workers the same way; with `threads` set (sharing the machine
        with other processes, as cluster tasks do) nothing is pinned. True with `threads` also
        places ONNX Runtime's workers.
    spinning: whether ONNX Runtime's idle intra-op threads spin (busy-wait) for work; None
        (default): not while the fast kernels are registered, where they would compete with the
        kernels' threads for the cores (docs/architecture.md, "Threads"), else ORT's default.
    providers: execution providers, e.g. ["CUDAExecutionProvider"] or ["cuda"] (default CPU).
    io_binding: keep the state in bound OrtValues between frames (default); False uses plain
        `session.run` with numpy state (the reference path, same results).
    shared_arena: on the CPU provider alone, take intermediate tensors from one arena shared
        by the Denoisers of the process that ask for it (`memory.share_cpu_arena`): several
        models or frame sizes run in turn need the memory of the largest frame, not the sum.
        It registers that arena in ONNX Runtime's environment, replacing one the host
        registered there, so it is opt-in; `denoise-bench compare` uses it. False (default):
        an arena of the session's own (ONNX Runtime's default), kept at its largest frame.
    learn, learn_every: for a model that learns while it runs (metadata `rtdenoise.online`,
        docs/contract.md): take its update step on frames 0, N, 2N, ... of each history
        (N = learn_every), none with learn=False (weights frozen). Ignored by other models.
    overrides: values of the model's run-time options (`contract.options`, e.g.
        {"kernel_size": 7}), fed as its overridable initializers `option.<name>` every frame.
    """

    def __init__(
        self,
        model: ModelSource,
        *,
        fast_kernels: bool | str = True,
        threads: int | None = None,
        pin_threads: bool | None = None,
        spinning: bool | None = None,
        providers: Sequence[Provider] | str | None = None,
        io_binding: bool = True,
        shared_arena: bool = False,
        learn: bool = True,
        learn_every: int = 1,
        overrides: Mapping[str, float] | None = None,
    ) -> None:
        if isinstance(model, (bytes, bytearray)):
            self.source, payload = "<model bytes>", bytes(model)
        else:
            path = resolve_model(model)
            self.source, payload = str(path), str(path)
        check_external_data(payload if isinstance(payload, bytes) else path)  # inside its folder
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
        self.threads = threads
        self.pin_threads = threads is None if pin_threads is None else pin_threads
        self.serial_below = SERIAL_KERNELS_BELOW
        self.bridge = ""  # how ONNX Runtime reaches the fast kernels: "native", "extensions"
        if fast_kernels:
            wanted_bridge = fast_kernels if isinstance(fast_kernels, str) else None
            self._fastops, self.bridge = _register_fast_kernels(options, wanted_bridge)
        else:
            self._fastops = None
        self.fast_kernels = self._fastops is not None
        if spinning is None and self.fast_kernels:
            spinning = False  # idle ORT workers would spin while a kernel needs the cores
        if spinning is not None:
            options.add_session_config_entry(ALLOW_SPINNING, "1" if spinning else "0")
        wanted = resolve_providers(providers)
        names = [p if isinstance(p, str) else p[0] for p in wanted]
        cpu_only = names == ["CPUExecutionProvider"]
        self.shared_arena = shared_arena and cpu_only and share_cpu_arena(options)
        try:
            self._session = ort.InferenceSession(payload, options, providers=wanted)
        except Exception as exc:  # onnxruntime's pybind errors derive from Exception only
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"{self.source}: ONNX Runtime cannot load the model: {first}") from exc
        got = self._session.get_providers()
        for name in names:
            if name not in got:
                raise InputError(
                    f"{self.source}: execution provider {name} failed to start (see ONNX "
                    f"Runtime's log); the session would run on {', '.join(got)}"
                )
        self._contract: Contract = contract_from_session(self._session, source=self.source)
        self._option_values = self._check_overrides(overrides or {})
        self._device = self._state_device(got)
        self._binding = self._session.io_binding() if io_binding else None
        self._static_hw = self._graph_static_hw()

        self.last_guard = GuardReport()  # what the input guard did to the last frame
        self.guard_totals = GuardTotals()
        self.last_nonfinite = 0  # pixels of the last frame with NaN/Inf in some buffer
        self.total_nonfinite = 0
        self.last_nonfinite_by_buffer: dict[str, int] = {}  # pixels per buffer
        self.last_state_nonfinite = 0
        self.total_state_nonfinite = 0
        self.last_run_ms = 0.0
        self.last_total_ms = 0.0
        self.frames_processed = 0
        self._size: tuple[int, int] | None = None  # unpadded H, W of the current history
        self._padded: tuple[int, int] | None = None
        self._slots: dict[str, list[_Slot]] = {}  # io-binding state, [current, next]
        self._state: dict[str, np.ndarray] = {}  # session.run state
        self._frame_index = 0
        self._pending_reset = True
        self._reset_reason = "first frame"
        self._lock = threading.Lock()  # one frame at a time (docs/reliability.md, "Threads")
        if learn_every < 1:
            raise InputError(f"learn_every must be >= 1, got {learn_every}")
        self.learn = learn
        self.learn_every = learn_every
        self._freeze = (self._contract.online or {}).get("freeze")

    # -- properties -------------------------------------------------------------------------

    @property
    def contract(self) -> Contract:
        return self._contract

    @property
    def family(self) -> str:
        return self._contract.family

    @property
    def config(self) -> dict[str, Any]:
        return dict(self._contract.config)

    @property
    def note(self) -> str:
        """The model's note on input preprocessing the caller must NOT do."""
        return self._contract.note

    @property
    def required_buffers(self) -> tuple[str, ...]:
        return self._contract.buffer_names

    @property
    def state_specs(self) -> tuple[StateSpec, ...]:
        return self._contract.state

    @property
    def pad_multiple(self) -> int:
        return self._contract.pad_multiple

    @property
    def options(self) -> dict[str, float]:
        """Every run-time option of the model with the value this session uses."""
        values = {o.name: o.default for o in self._contract.options}
        return values | {name: float(v) for name, (v, _) in self._option_values.items()}

    @property
    def frame_index(self) -> int:
        """Frames in the current history: 0 before the first frame and after a reset."""
        return 0 if self._pending_reset else self._frame_index

    @property
    def providers(self) -> list[str]:
        return self._session.get_providers()

    @property
    def online(self) -> dict[str, Any] | None:
        """The model's `rtdenoise.online` description (None: it does not learn while it runs)."""
        return self._contract.online

    def state_value(self, name: str) -> np.ndarray:
        """A copy of state `name` as the last frame left it (e.g. an online model's weights or
        loss); zeros before the first frame of a history."""
        if name not in {s.name for s in self.state_specs}:
            known = [s.name for s in self.state_specs]
            raise InputError(f"model {self.family!r} has no state {name!r} (state: {known})")
        if self._binding is not None:
            if name not in self._slots:
                raise InputError("no frame processed yet")
            slot = self._slots[name][0]
            return np.array(slot.host if slot.host is not None else slot.value.numpy())
        if name not in self._state:
            raise InputError("no frame processed yet")
        return np.array(self._state[name])

    @property
    def session(self) -> ort.InferenceSession:
        return self._session

    def __repr__(self) -> str:
        return (
            f"Denoiser({self.source!r}, family={self.family!r}, buffers={self.required_buffers}, "
            f"state={[s.name for s in self.state_specs]}, pad_multiple={self.pad_multiple}, "
            f"providers={self.providers}, fast_kernels={self.fast_kernels})"
        )

    # -- frame loop -------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the history: the next frame starts from zero state with reset = 1."""
        with self._lock:
            self._restart("reset()")

    def _restart(self, reason: str) -> None:
        """Start a new history at the next frame, noting why (the first reason wins)."""
        if not self._pending_reset:
            self._pending_reset, self._reset_reason = True, reason

    def process(
        self,
        buffers: Mapping[str, np.ndarray],
        *,
        reset: bool = False,
        assume_finite: bool = False,
        out: np.ndarray | None = None,
        channels_last: bool | None = None,
    ) -> np.ndarray:
        """Denoise one frame. buffers: name -> array, planar (C, H, W) or (1, C, H, W), or
        interleaved (H, W, C), (H, W, C + 1) with alpha ignored, or (H, W) when C = 1; float32
        or float16 (other real types are converted).

        Extra buffers are ignored. `reset=True` marks a camera cut. Returns the frame, linear
        HDR float32, (3, H, W), or (H, W, 3) when `color` is interleaved; or `out`, filled;
        always finite. Every buffer passes the input guard first (`rtdenoise.runtime.guard`:
        NaN/Inf replaced, values clamped to the buffer's range, isolated colour outliers
        removed, all in a copy); `last_guard` reports what it did, `last_nonfinite` counts the
        pixels that had NaN/Inf. A frame whose albedo, normal or depth is zero everywhere (a
        missing render pass) runs without history and the next frame starts a new one; so
        does the frame after an output with NaN/Inf (replaced by 0). An exception (a kernel's,
        Ctrl-C) leaves the history as it was before the call.
        assume_finite: accepted for callers of earlier versions; the guard runs regardless.
        out: the caller's output array, (3, H, W) or (H, W, 3) / (H, W, 4) (alpha left as it
            is), float32 or float16 (clamped to the half range); written in place, returned.
        channels_last: True: every array is interleaved; False: planar; None (default): each
            array's shape tells (one that fits both, an interleaved frame C pixels tall, is
            read as planar).
        """
        with self._lock:
            return self._process(buffers, reset, out, channels_last)

    def _process(
        self,
        buffers: Mapping[str, np.ndarray],
        reset: bool,
        out: np.ndarray | None,
        channels_last: bool | None,
    ) -> np.ndarray:
        start = time.perf_counter()
        feeds, (h, w), (hp, wp), report = self._prepare(buffers, channels_last)
        target = None if out is None else _output_view(out, (h, w), channels_last)
        if (h, w) != self._size and self._size is not None:
            self._restart(f"size change: {self._size[0]}x{self._size[1]} -> {h}x{w}")
        if reset:
            self._restart("reset=True")
        if report.unusable:
            self._restart(f"unusable frame: {', '.join(report.unusable)} zero everywhere")
        if self._pending_reset:
            report.reset = self._reset_reason
            self._start_history((h, w), (hp, wp))
        first = self._frame_index == 0
        self._write_controls()
        t0 = time.perf_counter()
        try:
            if self._binding is not None:
                result = self._run_bound(feeds, first, hp, wp)
            else:
                result = self._run_plain(feeds, first, hp, wp)
        except BaseException as exc:
            if first:  # the history this frame was to start has not started
                self._pending_reset = True
            if isinstance(exc, InputError) or not isinstance(exc, Exception):
                raise  # ContractError (the model broke the contract at run time), Ctrl-C
            raise RuntimeError(
                f"{self.source}: inference failed on frame {self.frames_processed} "
                f"({h}x{w}, padded {hp}x{wp}): {str(exc).strip().splitlines()[-1]}"
            ) from exc
        self.last_run_ms = (time.perf_counter() - t0) * 1e3
        self._frame_index += 1
        self.frames_processed += 1
        frame = result[0] if (hp, wp) == (h, w) else result[0, :, :h, :w]
        bad = replace_nonfinite("output", frame)  # in place: `result` is this call's own array
        if bad is not None:
            report.output_nonfinite = int(bad.sum())
            self._restart("non-finite output in the previous frame")
        if report.unusable:
            self._restart("previous frame unusable: " + ", ".join(report.unusable))
        self._note_guard(report)
        if target is not None:
            _store(target, frame)
        elif "color" in buffers and _is_interleaved(np.asarray(buffers["color"]), 3, channels_last):
            result = np.ascontiguousarray(frame.transpose(1, 2, 0))
        else:
            result = frame if (hp, wp) == (h, w) else np.ascontiguousarray(frame)
        self.last_total_ms = (time.perf_counter() - start) * 1e3
        return out if out is not None else result

    def _note_guard(self, report: GuardReport) -> None:
        self.last_guard = report
        self.guard_totals.add(report)
        self.last_nonfinite_by_buffer = dict(report.nonfinite)
        self.last_nonfinite = report.nonfinite_pixels
        self.total_nonfinite += report.nonfinite_pixels

    def _kernel_errors(self) -> AbstractContextManager[None]:
        """Raise a fast kernel's exception here, after the run (runtime/fastops.py)."""
        return self._fastops.raise_kernel_errors() if self._fastops else nullcontext()

    def _kernel_threads(self) -> int | None:
        """numba's thread count for the fast kernels of this run (`kernel_threads`); 1 without
        fast kernels, None for numba's own setting."""
        if not self._fastops:
            return 1
        if self._padded is None:
            return None
        return kernel_threads(self._padded, self.threads, self.serial_below)

    def _session_call(self, run: Callable[..., Any], *args: Any) -> Any:
        """`run(*args)` (a session run) with Ctrl-C held and a kernel's exception raised once
        it returns, before any state is swapped: a failed frame leaves the history as it was;
        the kernels on their thread count, the threads placed (`pin_threads`)."""
        team = self._kernel_threads()
        counted = self._fastops.kernel_threads(team) if self._fastops else nullcontext()
        where = placed(team) if self.pin_threads else nullcontext()
        with deferred_signals(), self._kernel_errors(), counted, where:
            return run(*args)

    def _prepare(
        self,
        buffers: Mapping[str, np.ndarray],
        channels_last: bool | None = None,
    ) -> tuple[dict[str, np.ndarray], tuple[int, int], tuple[int, int], GuardReport]:
        """Validate, guard and pad the buffers the model reads; interleaved and half-float
        buffers become planar float32 in one copy, which the guard may then fix in place."""
        if not isinstance(buffers, Mapping):
            raise InputError(f"process() takes a dict name -> array, got {type(buffers).__name__}")
        specs = self._contract.buffers
        missing = [s.name for s in specs if s.name not in buffers]
        if missing:
            given = ", ".join(sorted(map(str, buffers))) or "none"
            raise InputError(
                f"missing buffer {missing[0]!r}: model {self.family!r} needs "
                f"{', '.join(self.required_buffers)}; given: {given}"
            )
        arrays: dict[str, np.ndarray] = {}
        size: tuple[int, int] | None = None
        for spec in specs:
            a = self._check_shape(spec, np.asarray(buffers[spec.name]), channels_last)
            if size is None:
                size, first = a.shape[-2:], spec.name
            elif a.shape[-2:] != size:
                raise InputError(
                    f"buffer {spec.name!r} has shape {np.shape(buffers[spec.name])}; expected "
                    f"H x W = {size[0]} x {size[1]} like {first!r}"
                )
            arrays[spec.name] = a
        if size is None:  # a model that reads no buffers cannot tell the frame size
            raise InputError(f"model {self.family!r} lists no input buffers")
        h, w = size
        m = self.pad_multiple
        hp, wp = -(-h // m) * m, -(-w // m) * m
        if self._static_hw is not None and (hp, wp) != self._static_hw:
            sh, sw = self._static_hw
            raise InputError(f"model takes {sh}x{sw} frames only, got {h}x{w} (padded {hp}x{wp})")

        converted: dict[str, np.ndarray] = {}
        owned = []
        for name, a in arrays.items():
            a32 = np.ascontiguousarray(a, dtype=np.float32)
            if not np.may_share_memory(a32, np.asarray(buffers[name])):
                owned.append(name)  # a converted copy: the guard may fix it in place
            converted[name] = a32
        guarded, report = guard_buffers(converted, owned)  # never modifies the caller's arrays
        feeds = {name: _pad_edge(a, hp, wp) for name, a in guarded.items()}
        return feeds, (h, w), (hp, wp), report

    def _check_shape(
        self, spec: BufferSpec, a: np.ndarray, channels_last: bool | None = None
    ) -> np.ndarray:
        """(C, H, W) or (1, C, H, W) [rank 5: (S, C, H, W) or (1, S, C, H, W)], or interleaved
        (H, W, C[+1]) / (H, W) -> batched planar view."""
        given = a.shape
        good = a.dtype.kind in "fiu"
        if good and spec.rank == 4 and _is_interleaved(a, spec.channels, channels_last):
            a = (a[..., None] if a.ndim == 2 else a[..., : spec.channels]).transpose(2, 0, 1)
        if good and a.ndim == spec.rank - 1:
            a = a[None]
        good = good and a.ndim == spec.rank and a.shape[0] == 1
        good = good and (spec.channels is None or a.shape[-3] == spec.channels)
        good = good and min(a.shape[-2:], default=0) > 0
        if not good:
            batched = spec.expected.replace("(", "(1, ", 1)
            interleaved = "(H, W)" if spec.channels == 1 else f"(H, W, {spec.channels}[+alpha])"
            raise InputError(
                f"buffer {spec.name!r} has shape {given} and dtype {a.dtype}; expected "
                f"{spec.expected}, {batched} or {interleaved}, float32 or float16"
            )
        return a

    def _start_history(self, size: tuple[int, int], padded: tuple[int, int]) -> None:
        """Zero the state (allocating it at a new size) for a fresh history."""
        if padded != self._padded:
            self._slots, self._state = {}, {}
            hp, wp = padded
            for s in self.state_specs:
                if self._binding is not None:
                    shape = s.shape(hp, wp)
                    self._slots[s.name] = [_Slot(shape, self._device), _Slot(shape, self._device)]
                else:
                    self._state[s.name] = np.zeros(s.shape(hp, wp), np.float32)
            self._padded = padded
        else:
            for pair in self._slots.values():
                pair[0].zero()
            for a in self._state.values():
                a.fill(0.0)
        self._size = size
        self._frame_index = 0
        self._pending_reset = False

    def _write_controls(self) -> None:
        """An online model's freeze control for this frame: 0 = take the update step."""
        if self._freeze is None:
            return
        step = self.learn and self._frame_index % self.learn_every == 0
        value = 0.0 if step else 1.0
        if self._binding is None:
            self._state[self._freeze].fill(value)
            return
        slot = self._slots[self._freeze][0]
        if slot.host is not None:
            slot.host.fill(value)
        else:
            slot.value.update_inplace(np.full(slot.shape, value, np.float32))

    def _run_plain(self, feeds: dict[str, np.ndarray], first: bool, hp: int, wp: int) -> np.ndarray:
        inputs = dict(feeds)
        if self._contract.has_reset:
            inputs[RESET] = _RESET[first]
        for name, (value, _) in self._option_values.items():
            inputs[OPTION + name] = value
        for s in self.state_specs:
            inputs[s.input_name] = self._state[s.name]
        names = [OUTPUT] + [s.output_name for s in self.state_specs]
        out, *states = self._session_call(self._session.run, names, inputs)
        self._check_output_shape(out.shape, hp, wp)
        bad = 0
        for s, value in zip(self.state_specs, states, strict=True):
            if value.shape != s.shape(hp, wp):
                raise ContractError(
                    f"{self.source}: model broke the contract: {s.output_name} has shape "
                    f"{value.shape}, expected {s.shape(hp, wp)}"
                )
            n = _count_nonfinite(value)
            if n:
                np.nan_to_num(value, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
                bad += n
            self._state[s.name] = value
        self._note_state_nonfinite(bad)
        return out

    def _run_bound(self, feeds: dict[str, np.ndarray], first: bool, hp: int, wp: int) -> np.ndarray:
        io = self._binding
        io.clear_binding_inputs()
        io.clear_binding_outputs()
        for name, array in feeds.items():
            io.bind_cpu_input(name, array)
        if self._contract.has_reset:
            io.bind_cpu_input(RESET, _RESET[first])
        for name, (_, value) in self._option_values.items():
            io.bind_ortvalue_input(OPTION + name, value)  # bind_cpu_input refuses initializers
        for s in self.state_specs:
            current, following = self._slots[s.name]
            io.bind_ortvalue_input(s.input_name, current.value)
            io.bind_ortvalue_output(s.output_name, following.value)
        out = np.empty((1, 3, hp, wp), np.float32)
        io.bind_ortvalue_output(OUTPUT, ort.OrtValue.ortvalue_from_numpy(out))  # written in place
        self._session_call(self._session.run_with_iobinding, io)
        # On CPU check every state tensor (one cheap sum each); on a device only when the
        # output shows a problem, so that state stays on the device.
        check_state = self._device is None or _count_nonfinite(out) > 0
        bad = 0
        for pair in self._slots.values():
            pair.reverse()  # the state just written becomes the current one
            if check_state:
                bad += pair[0].sanitize()
        self._note_state_nonfinite(bad)
        return out

    def _note_state_nonfinite(self, bad: int) -> None:
        if bad and not self.total_state_nonfinite:
            warnings.warn(
                f"{self.source}: the model produced {bad} NaN/Inf state values on frame "
                f"{self.frames_processed}; replaced by 0 (a model bug)",
                RuntimeWarning,
                stacklevel=4,
            )
        self.last_state_nonfinite = bad
        self.total_state_nonfinite += bad

    def _check_output_shape(self, shape: tuple[int, ...], hp: int, wp: int) -> None:
        if tuple(shape) != (1, 3, hp, wp):
            raise ContractError(
                f"{self.source}: model broke the contract: output has shape {tuple(shape)}, "
                f"expected {(1, 3, hp, wp)}"
            )

    # -- setup helpers ----------------------------------------------------------------------

    def _check_overrides(
        self, overrides: Mapping[str, float]
    ) -> dict[str, tuple[np.ndarray, ort.OrtValue]]:
        """name -> (value as a float32 scalar, its OrtValue) for every overridden option."""
        known = {o.name: o for o in self._contract.options}
        inputs = {i.name for i in self._session.get_overridable_initializers()}
        values = {}
        for name, value in overrides.items():
            option = known.get(name)
            if option is None:
                raise InputError(
                    f"{self.source}: model {self.family!r} has no run-time option {name!r} "
                    f"(options: {', '.join(known) or 'none'})"
                )
            if option.input_name not in inputs:
                raise ContractError(
                    f"{self.source}: option {name!r} is declared but {option.input_name!r} is "
                    "not an overridable initializer of the graph"
                )
            array = np.array(option.check(value), np.float32)
            values[name] = (array, ort.OrtValue.ortvalue_from_numpy(array))
        return values

    def _state_device(self, providers: list[str]) -> tuple[str, int] | None:
        """Where bound state lives: None for host memory, else (device type, device id)."""
        for name in providers:
            device = _DEVICE_OF_PROVIDER.get(name)
            if device is None:
                continue
            options = self._session.get_provider_options().get(name, {})
            device_id = int(options.get("device_id", 0) or 0)
            try:
                ort.OrtValue.ortvalue_from_numpy(np.zeros(1, np.float32), device, device_id)
            except Exception as exc:
                warnings.warn(
                    f"cannot allocate state on {device}:{device_id} ({exc}); keeping it on host",
                    RuntimeWarning,
                    stacklevel=3,
                )
                return None
            return device, device_id
        return None

    def _graph_static_hw(self) -> tuple[int, int] | None:
        """(H, W) when the graph fixes them (non-dynamic export), else None."""
        for spec in self._contract.buffers:
            dims = spec.graph_shape[-2:]
            if all(isinstance(d, int) and d > 0 for d in dims):
                return int(dims[0]), int(dims[1])
        return None
