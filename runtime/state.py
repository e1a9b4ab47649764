"""The temporal state of a running model: two ping-pong buffers per state tensor.

Frame t reads buffer A of every tensor and writes buffer B, frame t+1 the reverse (`swap`). Bound
runs (ONNX Runtime's IO binding, the default) give ONNX Runtime the buffers themselves: with a
GPU execution provider they are device memory, so state never crosses to the host; on CPU they
are numpy arrays the session reads and writes in place. Plain runs (`session.run`, the reference
path) feed the current host arrays and hand the returned ones to `swap`, which copies them into
the next buffers: the same storage, the same swap, the same checks either way.

NaN/Inf never stays in the history: `swap` replaces them by 0 and counts them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import onnxruntime as ort

from .contract import ContractError, StateSpec
from .guard import count_nonfinite


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

    def fill(self, value: float) -> None:
        if self.host is not None:
            self.host.fill(value)
        else:
            self.value.update_inplace(np.full(self.shape, value, np.float32))

    def write(self, values: np.ndarray) -> None:
        if self.host is not None:
            np.copyto(self.host, values)
        else:
            self.value.update_inplace(np.ascontiguousarray(values, np.float32))

    def read(self) -> np.ndarray:
        """The values (the host array itself on CPU, a copy from a device)."""
        return self.host if self.host is not None else self.value.numpy()

    def sanitize(self) -> int:
        """Replace NaN/Inf by 0 in place; return how many there were."""
        host = self.read()
        bad = count_nonfinite(host)
        if bad:
            np.nan_to_num(host, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
            if self.host is None:
                self.value.update_inplace(host)
        return bad


class StateStore:
    """Every state tensor of a model at one padded frame size, as [current, next] slots."""

    def __init__(self, specs: Sequence[StateSpec], device: tuple[str, int] | None, source: str):
        self.specs = tuple(specs)
        self.device = device  # None: host memory
        self.source = source
        self.padded: tuple[int, int] | None = None
        self._slots: dict[str, list[_Slot]] = {}

    def start(self, padded: tuple[int, int], keep: Sequence[str] = ()) -> None:
        """Zero state for a new history, allocated anew when the padded size changes; the
        states named in `keep` carry their values over (across a size change too, where their
        shape does not depend on the frame size: an online model's weights)."""
        if padded != self.padded:
            old, hp, wp = self._slots, *padded
            self._slots = {
                s.name: [_Slot(s.shape(hp, wp), self.device), _Slot(s.shape(hp, wp), self.device)]
                for s in self.specs
            }
            for name in keep:
                if name in old and old[name][0].shape == self._slots[name][0].shape:
                    self._slots[name][0].write(old[name][0].read())
            self.padded = padded
        else:
            for name, pair in self._slots.items():
                if name not in keep:
                    pair[0].fill(0.0)

    @property
    def started(self) -> bool:
        return self.padded is not None

    def fill(self, name: str, value: float) -> None:
        """Set every value of the current state `name` (e.g. an online model's freeze flag)."""
        self._slots[name][0].fill(value)

    def current(self, name: str) -> np.ndarray:
        """The current values of state `name` (the host array itself on CPU)."""
        return self._slots[name][0].read()

    def bind(self, io: ort.IOBinding) -> None:
        """Bind the current buffers as the inputs and the next ones as the outputs of a run."""
        for s in self.specs:
            current, following = self._slots[s.name]
            io.bind_ortvalue_input(s.input_name, current.value)
            io.bind_ortvalue_output(s.output_name, following.value)

    def feeds(self) -> dict[str, np.ndarray]:
        """The current buffers as the state inputs of a plain run."""
        return {s.input_name: self._slots[s.name][0].read() for s in self.specs}

    @property
    def output_names(self) -> list[str]:
        return [s.output_name for s in self.specs]

    def swap(self, written: Iterable[np.ndarray] | None = None, check: bool = True) -> int:
        """Make the state just written the current one: a bound run wrote the next buffers
        (`written` None), a plain run returned `written` (one array per spec, copied into
        them). With `check`, NaN/Inf are replaced by 0 in the new state; returns how many."""
        if written is not None:
            hp, wp = self.padded
            for s, value in zip(self.specs, written, strict=True):
                if value.shape != s.shape(hp, wp):
                    raise ContractError(
                        f"{self.source}: model broke the contract: {s.output_name} has shape "
                        f"{value.shape}, expected {s.shape(hp, wp)}"
                    )
                self._slots[s.name][1].write(value)
        bad = 0
        for pair in self._slots.values():
            pair.reverse()
            if check:
                bad += pair[0].sanitize()
        return bad
