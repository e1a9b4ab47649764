"""The stateful executor: one ONNX Runtime session driving any contract-v1 model, frame by
frame (docs/architecture.md, "Runtime"; docs/contract.md).

Per frame: the buffers made planar float32 (`arrays`), passed through the input guard (`guard`:
NaN/Inf replaced, ranges clamped, colour outliers removed, all counted) and replicate-padded:
the model's `edge_margin` on every side (if it declares one), then to its `pad_multiple`; the
run, with the state fed in and the next state written (`state`: ping-pong buffers, bound
through ONNX Runtime's IO binding by default); the output cropped (NaN/Inf in it replaced by 0
and counted). State is zero-filled and `reset` = 1 on the first frame, after `reset()`, when
the resolution changes, on a frame whose guide buffers are missing (zero everywhere) and on the
frame after it or after a non-finite output (docs/reliability.md). The session, its providers,
threads and fast kernels: `session`.

Fast kernels run as custom ops inside `session.run`; an exception there must not unwind through
ONNX Runtime, so the run is wrapped in `bridge.raise_kernel_errors()` (the kernel's error is
raised after the run) and in `deferred_signals()` (Ctrl-C is raised after the run). One frame
at a time: `process` and `reset` hold a lock, so an instance shared by threads serialises their
calls (docs/reliability.md, "Threads").
"""

from __future__ import annotations

import threading
import time
import warnings
from collections.abc import Mapping, Sequence
from contextlib import nullcontext
from typing import Any

import numpy as np
import onnxruntime as ort

from . import bridge
from .arrays import output_view, pad_edge, padded_size, planar_frame, returned_frame, store
from .contract import (
    OPTION,
    OUTPUT,
    RESET,
    Contract,
    ContractError,
    StateSpec,
    contract_from_session,
)
from .errors import InputError
from .guard import GuardReport, GuardTotals, count_nonfinite, guard_buffers, replace_nonfinite
from .interrupts import deferred_signals
from .online import OnlineControls
from .placement import placed
from .session import (
    SERIAL_KERNELS_BELOW,
    ModelSource,
    Provider,
    checked_model,
    kernel_thread_count,
    open_session,
    option_values,
)
from .state import StateStore

_RESET = {True: np.array(1.0, np.float32), False: np.array(0.0, np.float32)}


class Denoiser:
    """Run a contract-v1 ONNX denoiser frame by frame, keeping its temporal state.

    model: a path to an .onnx file, `demo:<family>`, or the serialized model bytes.
    fast_kernels: register the fast kernels of the rtdenoise custom ops; False runs their
        portable ONNX function bodies, inlined by ONNX Runtime. True picks the fastest path
        that holds every op of the model: "native-cpp" (the C++ library rtdenoise_ops, no
        Python in the run) where it was built and holds them all and the environment
        variable RTDENOISE_NATIVE_OPS is not "0", else the numba kernels (the
        `numba` extra) through "native" (the compiled bridge, zero-copy) or "extensions"
        (onnxruntime-extensions, which copies every input and output); with neither, the
        portable bodies, with one warning per process. A string asks for one of these
        (InputError where it is not installed); "native" forces the numba kernels. `bridge`
        says which one runs.
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
    relearn_at_cuts: a reset (`reset()`, a cut) of such a model also restarts its learning
        (weights at initialisation, optimiser moments zero); by default it keeps what it
        learned, across size changes too (`reset(learning=True)` restarts it once).
    overrides: values of the model's run-time options (`contract.options`, e.g.
        {"kernel_size": 7}), fed as its overridable initializers `option.<name>` every frame.
    layout: which form of a model's layout-dependent convs loads (docs/contract.md, "Layout
        forms"): "nchwc16" (AVX-512's blocks), "plain", or None (default: chosen for this CPU
        and provider, runtime/layout.py). `layout` says which loaded ("" for a model without).
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
        relearn_at_cuts: bool = False,
        overrides: Mapping[str, float] | None = None,
        layout: str | None = None,
    ) -> None:
        checked = checked_model(model)
        self.source = checked.source
        opened = open_session(
            checked.payload,
            self.source,
            fast_kernels=fast_kernels,
            threads=threads,
            pin_threads=pin_threads,
            spinning=spinning,
            providers=providers,
            shared_arena=shared_arena,
            ops=checked.ops,
            layout=layout,
            layout_forms=checked.layout_forms,
        )
        self._session = opened.session
        self.bridge = opened.bridge  # how ONNX Runtime reaches the fast kernels, "" for none
        self.fast_kernels = bool(opened.bridge)
        self.layout = opened.layout  # the conv forms loaded (runtime/layout.py), "" none
        self.threads = opened.threads
        self.pin_threads = opened.pin_threads
        self.shared_arena = opened.shared_arena
        self.serial_below = SERIAL_KERNELS_BELOW
        self._contract: Contract = contract_from_session(self._session, source=self.source)
        self._option_values = option_values(
            self._session, self._contract, overrides or {}, self.source
        )
        self._binding = self._session.io_binding() if io_binding else None
        self._device = opened.device if io_binding else None
        self._state = StateStore(self.state_specs, self._device, self.source)
        self._static_hw = self._contract.static_size

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
        self._frame_index = 0
        self._pending_reset = True
        self._reset_reason = "first frame"
        self._lock = threading.Lock()  # one frame at a time (docs/reliability.md, "Threads")
        if learn_every < 1:
            raise InputError(f"learn_every must be >= 1, got {learn_every}")
        self.learn, self.learn_every, self.relearn_at_cuts = learn, learn_every, relearn_at_cuts
        self._online = OnlineControls(self._contract.online)

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
    def edge_margin(self) -> int:
        """Pixels of the frame's edge repeated on every side before the model (then cropped)."""
        return self._contract.edge_margin

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
        if not self._state.started:
            raise InputError("no frame processed yet")
        return np.array(self._state.current(name))

    @property
    def session(self) -> ort.InferenceSession:
        return self._session

    def __repr__(self) -> str:
        return (
            f"Denoiser({self.source!r}, family={self.family!r}, buffers={self.required_buffers}, "
            f"state={[s.name for s in self.state_specs]}, pad_multiple={self.pad_multiple}, "
            f"edge_margin={self.edge_margin}, "
            f"providers={self.providers}, fast_kernels={self.fast_kernels})"
        )

    # -- frame loop -------------------------------------------------------------------------

    def reset(self, learning: bool | None = None) -> None:
        """Forget the history: the next frame starts from zero state with reset = 1. A model
        that learns while it runs keeps what it learned unless `learning` (default:
        `relearn_at_cuts`) restarts that too."""
        with self._lock:
            self._restart("reset()")
            if self.relearn_at_cuts if learning is None else learning:
                self._online.restart_learning()

    def _restart(self, reason: str) -> None:
        """Start a new history at the next frame, noting why (the first reason wins)."""
        if not self._pending_reset:
            self._pending_reset, self._reset_reason = True, reason

    def process(
        self,
        buffers: Mapping[str, np.ndarray],
        *,
        reset: bool = False,
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
        target = None if out is None else output_view(out, (h, w), channels_last)
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
        self._online.write(self._state, self._frame_index, self.learn, self.learn_every)
        t0 = time.perf_counter()
        try:
            result = self._run(feeds, first, hp, wp)
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
        cropped = (hp, wp) != (h, w)
        m = self.edge_margin
        frame = result[0, :, m : m + h, m : m + w] if cropped else result[0]
        bad = replace_nonfinite("output", frame)  # in place: `result` is this call's own array
        if bad is not None:
            report.output_nonfinite = int(bad.sum())
            self._restart("non-finite output in the previous frame")
        if report.unusable:
            self._restart("previous frame unusable: " + ", ".join(report.unusable))
        if self.last_state_nonfinite and self._online.learned:
            self._restart("non-finite state in the previous frame")
        self._note_guard(report)
        if target is not None:
            store(target, frame)
        else:
            frame = returned_frame(frame, buffers.get("color"), channels_last, cropped)
        self.last_total_ms = (time.perf_counter() - start) * 1e3
        return out if out is not None else frame

    def _note_guard(self, report: GuardReport) -> None:
        self.last_guard = report
        self.guard_totals.add(report)
        self.last_nonfinite_by_buffer = dict(report.nonfinite)
        self.last_nonfinite = report.nonfinite_pixels
        self.total_nonfinite += report.nonfinite_pixels

    def _prepare(
        self, buffers: Mapping[str, np.ndarray], channels_last: bool | None
    ) -> tuple[dict[str, np.ndarray], tuple[int, int], tuple[int, int], GuardReport]:
        """Validate, guard and pad the buffers the model reads; interleaved and half-float
        buffers become planar float32 in one copy, which the guard may then fix in place."""
        arrays, owned, size = planar_frame(
            self._contract.buffers, buffers, channels_last, self.family
        )
        hp, wp = padded_size(size, self.pad_multiple, self.edge_margin)
        if self._static_hw is not None and (hp, wp) != self._static_hw:
            sh, sw = self._static_hw
            raise InputError(
                f"model takes {sh}x{sw} frames only, got {size[0]}x{size[1]} (padded {hp}x{wp})"
            )
        guarded, report = guard_buffers(arrays, owned)  # never modifies the caller's arrays
        feeds = {name: pad_edge(a, hp, wp, self.edge_margin) for name, a in guarded.items()}
        return feeds, size, (hp, wp), report

    def _start_history(self, size: tuple[int, int], padded: tuple[int, int]) -> None:
        """Zero the state (allocating it at a new size) for a fresh history, but for what an
        online model learned unless its learning restarts too."""
        self._online.start_history(self._state, padded)
        self._size = size
        self._frame_index = 0
        self._pending_reset = False

    def _run(self, feeds: dict[str, np.ndarray], first: bool, hp: int, wp: int) -> np.ndarray:
        """One session run: the frame's buffers, reset and options in, the output and the next
        state out (`self._state` swapped, NaN/Inf in it replaced and counted)."""
        controls = {RESET: _RESET[first]} if self._contract.has_reset else {}
        if self._binding is None:
            inputs = feeds | controls | self._state.feeds()
            inputs |= {OPTION + name: value for name, (value, _) in self._option_values.items()}
            out, *written = self._session_call(
                self._session.run, [OUTPUT, *self._state.output_names], inputs
            )
            self._check_output_shape(out.shape, hp, wp)
            self._note_state_nonfinite(self._state.swap(written))
            return out
        io = self._binding
        io.clear_binding_inputs()
        io.clear_binding_outputs()
        for name, array in (feeds | controls).items():
            io.bind_cpu_input(name, array)
        for name, (_, value) in self._option_values.items():
            io.bind_ortvalue_input(OPTION + name, value)  # bind_cpu_input refuses initializers
        self._state.bind(io)
        out = np.empty((1, 3, hp, wp), np.float32)
        io.bind_ortvalue_output(OUTPUT, ort.OrtValue.ortvalue_from_numpy(out))  # written in place
        self._session_call(self._session.run_with_iobinding, io)
        # On CPU check every state tensor (one cheap sum each); on a device only when the
        # output shows a problem, so that state stays on the device.
        check = self._device is None or count_nonfinite(out) > 0
        self._note_state_nonfinite(self._state.swap(check=check))
        return out

    def _session_call(self, run: Any, *args: Any) -> Any:
        """`run(*args)` (a session run) with Ctrl-C held and a kernel's exception raised once
        it returns, before any state is swapped: a failed frame leaves the history as it was;
        the kernels on their thread count, the threads placed (`pin_threads`)."""
        if not self.fast_kernels:
            with deferred_signals(), placed(1) if self.pin_threads else nullcontext():
                return run(*args)
        team = kernel_thread_count(self._state.padded, self.threads, self.serial_below)
        # The C++ kernels' threads start inside the run and inherit the caller's affinity:
        # pinning the caller to one CPU would put them all there.
        pin = self.pin_threads and self.bridge != "native-cpp"
        where = placed(team) if pin else nullcontext()
        threads = bridge.kernel_threads(self.bridge, team)
        with deferred_signals(), bridge.raise_kernel_errors(), threads, where:
            return run(*args)

    def _note_state_nonfinite(self, bad: int) -> None:
        if bad and self._online.learned:  # weights zeroed in place: learn anew
            self._online.restart_learning()
        if bad and not self.total_state_nonfinite:
            warnings.warn(
                f"{self.source}: the model produced {bad} NaN/Inf state values on frame "
                f"{self.frames_processed}; replaced by 0 (a model bug)",
                RuntimeWarning,
                stacklevel=5,
            )
        self.last_state_nonfinite = bad
        self.total_state_nonfinite += bad

    def _check_output_shape(self, shape: tuple[int, ...], hp: int, wp: int) -> None:
        if tuple(shape) != (1, 3, hp, wp):
            raise ContractError(
                f"{self.source}: model broke the contract: output has shape {tuple(shape)}, "
                f"expected {(1, 3, hp, wp)}"
            )
