"""Drive an exported rtdenoise model with nothing but onnxruntime and numpy.

This is the contract v1 loop (docs/contract.md, "Driving a model") that a host in any language
implements: read the metadata, pad every buffer to the model's multiple, zero the state and set
`reset = 1` on the first frame, at a camera cut and on a size change, feed `state_next.*` back as
`state.*`, crop the output. The custom ops of the `rtdenoise` domain run on a stock onnxruntime
through the standard-op function bodies every exported file carries.

    python examples/plain_onnxruntime_host.py rtdenoise/assets/models/wskp.onnx

runs the model over a few synthetic frames with a camera cut halfway. tests/test_examples.py
checks that it matches `rtdenoise.runtime.Denoiser` on the shipped models.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import onnxruntime as ort


def pad_edge(a: np.ndarray, hp: int, wp: int) -> np.ndarray:
    """Repeat the last row and column of `a` (..., H, W) up to (..., hp, wp)."""
    h, w = a.shape[-2:]
    widths = [(0, 0)] * (a.ndim - 2) + [(0, hp - h), (0, wp - w)]
    return np.pad(a, widths, mode="edge")


class PlainHost:
    """One model, one sequence at a time: the state lives here between frames."""

    def __init__(self, model_path: str) -> None:
        self.session = ort.InferenceSession(model_path, providers=["CPUExecutionProvider"])
        meta = self.session.get_modelmeta().custom_metadata_map
        if meta.get("rtdenoise.contract") != "1":
            raise ValueError(f"{model_path}: not an rtdenoise contract v1 model")
        self.buffers = json.loads(meta["rtdenoise.inputs"])["buffers"]  # in graph-input order
        # [{"name", "channels", "scale"}], plus "size": [h, w] for a state that does not follow
        # the frame (e.g. the weights of a model that learns while it runs)
        self.state = json.loads(meta["rtdenoise.state"])
        self.pad = int(meta["rtdenoise.pad_multiple"])
        self.has_reset = any(i.name == "reset" for i in self.session.get_inputs())
        self.outputs = ["output"] + [f"state_next.{s['name']}" for s in self.state]
        self.history: dict[str, np.ndarray] | None = None  # None: the next frame starts anew
        self.size: tuple[int, int] | None = None

    def reset(self) -> None:
        """A camera cut: forget the history."""
        self.history = None

    def process(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """frame: buffer name -> (C, H, W) float32, free of NaN/Inf. Returns (3, H, W)."""
        h, w = frame[self.buffers[0]].shape[-2:]
        hp, wp = -(-h // self.pad) * self.pad, -(-w // self.pad) * self.pad
        first = self.history is None or (h, w) != self.size
        if first:
            self.history = {
                s["name"]: np.zeros(
                    (1, s["channels"], *(s.get("size") or (hp // s["scale"], wp // s["scale"]))),
                    "f4",
                )
                for s in self.state
            }
            self.size = (h, w)
        feeds = {b: pad_edge(np.asarray(frame[b], np.float32), hp, wp)[None] for b in self.buffers}
        if self.has_reset:
            feeds["reset"] = np.array(1.0 if first else 0.0, np.float32)
        feeds |= {f"state.{name}": value for name, value in self.history.items()}
        output, *state = self.session.run(self.outputs, feeds)
        self.history = {s["name"]: v for s, v in zip(self.state, state, strict=True)}
        return output[0, :, :h, :w]


def synthetic_frame(buffers: list[str], t: int, h: int = 48, w: int = 64) -> dict[str, np.ndarray]:
    """Frame t of a noisy gradient moving 2 pixels right per frame, over a flat wall."""
    rng = np.random.default_rng(t)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    clean = np.stack([(x + 2 * t) / w, y / h, np.full_like(x, 0.5)])
    one, zero = np.ones((h, w), np.float32), np.zeros((h, w), np.float32)
    made = {
        "color": clean * rng.exponential(1.0, clean.shape),
        "color_b": clean * rng.exponential(1.0, clean.shape),  # an independent estimate
        "albedo": np.stack([0.5 * one] * 3),
        "normal": np.stack([zero, zero, one]),
        "depth": 5 * one[None],
        "motion": np.stack([-2 * one, zero]),  # previous position = current + motion
    }
    return {b: made[b].astype(np.float32) for b in buffers}


def main(model_path: str, frames: int = 8) -> None:
    host = PlainHost(model_path)
    print(f"{model_path}: buffers {host.buffers}, state {[s['name'] for s in host.state]}")
    for t in range(frames):
        if t == frames // 2:
            host.reset()  # a camera cut
        out = host.process(synthetic_frame(host.buffers, t))
        print(f"frame {t}: output {out.shape}, mean {out.mean():.4f}")


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) for a in sys.argv[2:3]))
