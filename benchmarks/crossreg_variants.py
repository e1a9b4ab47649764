"""demo:crossreg's weights under config overrides, online learning on as shipped (PyTorch eager,
one thread): every metric on the committed and the validation sequences, and where the output is
worse than the noisy input. Each argument is one variant, a JSON object of config overrides
(`{}` = the shipped config):

    python benchmarks/crossreg_variants.py '{}' '{"history_clamp": 0}' '{"history_clamp": 2}'
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.sequences.frames import (
    find_frames,
    match_references,
    read_frame,
    read_reference,
)
from rtdenoise.runtime.sequences.metrics import SequenceMetrics
from rtdenoise.shipped import demo_model, sample_sequences

VALIDATION = Path(__file__).resolve().parents[1] / "validation"
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "smape": False, "relmse": False}


def load_sequence(folder: Path) -> tuple[list[dict], list[np.ndarray]]:
    frames = find_frames(folder)
    refs = [read_reference(r) for r in match_references(frames)]
    return [read_frame(p).buffers for p in frames], refs


def run(model, frames: list[dict], refs: list[np.ndarray]) -> tuple[dict, dict]:
    """Summaries of the output and of the noisy input over one sequence (learning on)."""
    h, w = frames[0]["color"].shape[-2:]
    state = model.initial_state(1, h, w)
    out_m, in_m = SequenceMetrics(), SequenceMetrics()
    with torch.no_grad():
        for t, (frame, ref) in enumerate(zip(frames, refs, strict=True)):
            buffers = {k: torch.from_numpy(np.ascontiguousarray(v[None])) for k, v in frame.items()}
            state["keep"] = torch.full_like(state["keep"], 0.0 if t == 0 else 1.0)
            out, state = model(buffers, state, torch.tensor(1.0 if t == 0 else 0.0))
            out_m.add(out[0].numpy(), ref)
            in_m.add(frame["color"], ref)
    return out_m.summary(), in_m.summary()


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    ckpt = read_checkpoint(demo_model("crossreg", ".pt"))
    names = [(f"committed seq_{i:03d}", s) for i, s in enumerate(sample_sequences())]
    names += [(f"validation seq_{i:03d}", VALIDATION / f"seq_{i:03d}") for i in range(8)]
    data = {name: load_sequence(folder) for name, folder in names}
    for spec in argv or ["{}"]:
        model = build_model("crossreg", {**ckpt["config"], **json.loads(spec)})
        model.load_state_dict(ckpt["state_dict"])
        rows = {name: run(model, *seq) for name, seq in data.items()}
        worse = [
            f"{name} {m}"
            for name, (out, noisy) in rows.items()
            for m, higher in HIGHER_IS_BETTER.items()
            if (out[m] < noisy[m] if higher else out[m] > noisy[m])
        ]
        committed = [out for name, (out, _) in rows.items() if name.startswith("committed")]
        val = [out for name, (out, _) in rows.items() if name.startswith("validation")]
        mean = {m: np.mean([v[m] for v in val]) for m in ("psnr", "ssim", "relmse", "trmae")}
        fmt = lambda rows, m, spec: " ".join(format(v[m], spec) for v in rows)  # noqa: E731
        print(
            f"{spec}\n  committed PSNR {fmt(committed, 'psnr', '.2f')}"
            f", relMSE {fmt(committed, 'relmse', '.3f')}"
            f"\n  validation mean PSNR {mean['psnr']:.3f} SSIM {mean['ssim']:.4f}"
            f" relMSE {mean['relmse']:.3f} TRMAE {mean['trmae']:.3f};"
            f" per sequence {fmt(val, 'psnr', '.2f')}"
            f"\n  worse than the noisy input: {', '.join(worse) or 'nowhere'}",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
