"""Where a model loses to OIDN high: PSNR (tau-mapped, pooled) on the validation frames without
history (the first, and the first after a cut) and on those with history, per sequence. The
frames, cuts and both denoisers are `denoise-bench compare`'s (runtime.sequences.compare).

    python benchmarks/history_split.py demo:nbg [--sequence validation/seq_003 ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.sequences.compare import (
    Contender,
    load_sequences,
    model_contender,
    oidn_contender,
    walk,
)
from rtdenoise.runtime.sequences.metrics import mse_tonemapped, psnr_from_mse

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def split(ours: Contender, oidn: Contender, folder: Path) -> str:
    buffers = sorted(set(ours.buffers) | set(oidn.buffers))
    [(_, frames, refs, starts)] = load_sequences([folder], buffers)
    a, b = (
        np.array([mse_tonemapped(o, r) for o, r in zip(walk(c, frames, starts), refs, strict=True)])
        for c in (ours, oidn)
    )
    fresh = np.array([i == 0 or i in starts for i in range(len(frames))])

    def part(mask: np.ndarray) -> str:
        x, y = psnr_from_mse(float(a[mask].mean())), psnr_from_mse(float(b[mask].mean()))
        return f"{x:.2f} vs {y:.2f} ({x - y:+.2f})"

    everything = np.ones_like(fresh)
    return (
        f"{folder.name}: all {part(everything)} | without history {part(fresh)}"
        f" | with history {part(~fresh)} | share of the model's error without history"
        f" {a[fresh].sum() / a.sum():.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("model")
    ap.add_argument("--sequence", type=Path, action="append")
    args = ap.parse_args()
    ours = model_contender(args.model, Denoiser(args.model))
    oidn = oidn_contender("high")
    for folder in args.sequence or sorted(VALIDATION.glob("seq_*")):
        print(split(ours, oidn, folder), flush=True)


if __name__ == "__main__":
    main()
