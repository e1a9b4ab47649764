"""The host's side of a model that learns while it runs (docs/contract.md, "Online learning"):
the controls it writes before each frame and what a new history keeps of the learning.

`freeze` (1 skips this frame's update) follows `learn` / `learn_every`. `keep` (1: the graph
goes on from the learned weights after a reset) is 1 on every history but the first and those
after `restart_learning()`; the learned states (weights, optimiser moments, step, statistics)
then carry over the reset, across a size change too. A model without `keep` restarts its
learning at every reset, as the graph decides alone.
"""

from __future__ import annotations

from typing import Any

from .contract import learning_states
from .state import StateStore


class OnlineControls:
    """What `Denoiser` writes into an online model's control states, frame by frame."""

    def __init__(self, online: dict[str, Any] | None) -> None:
        online = online or {}
        self.freeze, self.keep = online.get("freeze"), online.get("keep")
        self.learned = learning_states(online) if self.keep else ()
        self._relearn = True  # the first history starts the learning
        self._keep_value = 0.0

    def restart_learning(self) -> None:
        """The next history starts the learning anew (weights at initialisation)."""
        self._relearn = True

    def start_history(self, store: StateStore, padded: tuple[int, int]) -> None:
        """Zero `store` for a new history, keeping the learned states unless the learning
        restarts too."""
        kept = self.learned if store.started and not self._relearn else ()
        store.start(padded, keep=kept)
        self._keep_value, self._relearn = (1.0 if kept else 0.0), False

    def write(self, store: StateStore, frame_index: int, learn: bool, every: int) -> None:
        """The controls of frame `frame_index` of the history: an update step on frames 0,
        every, 2 every, ... while `learn`."""
        if self.freeze is not None:
            step = learn and frame_index % every == 0
            store.fill(self.freeze, 0.0 if step else 1.0)
        if self.keep is not None:
            store.fill(self.keep, self._keep_value)
