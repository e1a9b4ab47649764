"""Drive an exported rtdenoise model with nothing but onnxruntime and numpy.

This is the contract v1 loop (docs/contract.md, "Driving a model") that a host in any language
implements: read the metadata, pad every buffer (the model's edge margin on every side, then up
to its multiple), zero the state and set
`reset = 1` on the first frame, at a camera cut and on a size change, feed `state_next.*` back as
`state.*`, crop the output. A per-sample model (affinity) reads the rank-5 `samples` buffer,
(S, C, H, W) per frame: its C features are the buffers the model's config lists under
`sample_features`; a frame with only pixel buffers gives S = 1 from them. The custom ops of
the `rtdenoise` domain run on a stock onnxruntime through the standard-op function bodies
every exported file carries.

    python examples/plain_onnxruntime_host.py rtdenoise/assets/models/wskp.onnx

runs the model over a few synthetic frames with a camera cut halfway. tests/test_examples.py
checks that it matches `rtdenoise.runtime.Denoiser` on the shipped models.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence

import numpy as np
import onnxruntime as ort

SAMPLES = "samples"  # the rank-5 per-sample buffer (docs/contract.md, "Buffers")
DEFAULT_SAMPLE_FEATURES = ("color", "albedo", "normal", "depth")  # when the config names none


def pad_edge(a: np.ndarray, hp: int, wp: int, margin: int = 0) -> np.ndarray:
    """Repeat the edge rows and columns of `a` (..., H, W): `margin` on the top and left, the
    rest up to (..., hp, wp) on the bottom and right."""
    h, w = a.shape[-2:]
    widths = [(0, 0)] * (a.ndim - 2) + [(margin, hp - h - margin), (margin, wp - w - margin)]
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
        self.margin = int(meta.get("rtdenoise.edge_margin", "0"))  # optional: 0 if absent
        config = json.loads(meta.get("rtdenoise.config", "{}"))
        self.sample_features = config.get("sample_features", DEFAULT_SAMPLE_FEATURES)
        self.has_reset = any(i.name == "reset" for i in self.session.get_inputs())
        self.outputs = ["output"] + [f"state_next.{s['name']}" for s in self.state]
        self.history: dict[str, np.ndarray] | None = None  # None: the next frame starts anew
        self.size: tuple[int, int] | None = None

    def reset(self) -> None:
        """A camera cut: forget the history."""
        self.history = None

    def with_samples(self, frame: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The frame with `samples` (S, C, H, W) where the model reads it and the frame has
        none: S = 1 from its pixel buffers, the model's sample features in order."""
        if SAMPLES not in self.buffers or SAMPLES in frame:
            return frame
        missing = [f for f in self.sample_features if f not in frame]
        if missing:
            raise KeyError(f"no {SAMPLES!r} and no pixel buffer {missing[0]!r} to make S = 1 from")
        one = np.concatenate([np.asarray(frame[f], np.float32) for f in self.sample_features])
        return {**frame, SAMPLES: one[None]}

    def process(self, frame: dict[str, np.ndarray]) -> np.ndarray:
        """frame: buffer name -> (C, H, W) float32 ((S, C, H, W) for `samples`), free of
        NaN/Inf. Returns (3, H, W)."""
        frame = self.with_samples(frame)
        h, w = frame[self.buffers[0]].shape[-2:]
        m, pad = self.margin, self.pad
        hp, wp = -(-(h + 2 * m) // pad) * pad, -(-(w + 2 * m) // pad) * pad
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
        feeds = {
            b: pad_edge(np.asarray(frame[b], np.float32), hp, wp, m)[None] for b in self.buffers
        }
        if self.has_reset:
            feeds["reset"] = np.array(1.0 if first else 0.0, np.float32)
        feeds |= {f"state.{name}": value for name, value in self.history.items()}
        output, *state = self.session.run(self.outputs, feeds)
        self.history = {s["name"]: v for s, v in zip(self.state, state, strict=True)}
        return output[0, :, m : m + h, m : m + w]


def synthetic_frame(
    buffers: list[str],
    t: int,
    h: int = 48,
    w: int = 64,
    sample_features: Sequence[str] = DEFAULT_SAMPLE_FEATURES,
    spp: int = 2,
) -> dict[str, np.ndarray]:
    """Frame t of a noisy gradient moving 2 pixels right per frame, over a flat wall; with
    `samples` among the buffers, `spp` samples of their own noise, `color` their mean."""
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
    if SAMPLES in buffers:
        own = [clean * rng.exponential(1.0, clean.shape) for _ in range(spp)]
        made["color"] = np.mean(own, axis=0)
        made[SAMPLES] = np.stack(
            [np.concatenate([c if f == "color" else made[f] for f in sample_features]) for c in own]
        )
    return {b: made[b].astype(np.float32) for b in buffers}


def main(model_path: str, frames: int = 8) -> None:
    host = PlainHost(model_path)
    print(f"{model_path}: buffers {host.buffers}, state {[s['name'] for s in host.state]}")
    for t in range(frames):
        if t == frames // 2:
            host.reset()  # a camera cut
        out = host.process(synthetic_frame(host.buffers, t, sample_features=host.sample_features))
        print(f"frame {t}: output {out.shape}, mean {out.mean():.4f}")


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) for a in sys.argv[2:3]))
