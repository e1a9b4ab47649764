"""How much a small light's history bleeds into its dark neighbours, per TA reprojection.

Runs TemporalAccumulation alone (no network: its torch form, models.temporal) over a sequence
with the reprojections per_tap 1 (SVGF), 2 (per tap, outlier-bright taps weighed down) and 3
(weighed down by the square), the colour demodulated by albedo + 0.01 as the accumulating
families do, and reports per frame the largest remodulated accumulated value at pixels whose
reference is dark (channel mean < 0.1), then over frames 4 on: relMSE, mean |T(out) - T(ref)|
with T(x) = x / (1 + x), and the mean brightness of the accumulation over the reference's (the
bias of the weighting).

    python benchmarks/history_bleed.py rtdenoise/assets/sequences/seq_000 validation/seq_00*
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from rtdenoise.models.ops.temporal_accumulation import temporal_accumulation
from rtdenoise.models.temporal import TemporalConfig
from rtdenoise.runtime.sequences.frames import (
    find_frames,
    match_references,
    read_frame,
    read_reference,
)

ALBEDO_EPS = 1e-2  # models.accumulation.AccumulatingConfig.albedo_eps


def accumulate(folder: str, per_tap: int) -> tuple[list[float], float, float, float]:
    """(dark max per frame, relMSE, tonemapped L1, brightness ratio) of TA over `folder`."""
    paths = find_frames(folder)
    refs = [read_reference(r) for r in match_references(paths)]
    config = TemporalConfig(per_tap=per_tap)
    dark_max, rel, l1, ratio = [], [], [], []
    ta = geometry = None
    for t, (path, ref) in enumerate(zip(paths, refs, strict=True)):
        b = {k: torch.from_numpy(v)[None] for k, v in read_frame(path).buffers.items()}
        modulation = b["albedo"] + ALBEDO_EPS
        current = b["color"] / modulation
        if ta is None:
            ta = torch.zeros(1, current.shape[1] + 1, *current.shape[2:])
            geometry = torch.zeros(1, 4, *current.shape[2:])
        reset = torch.tensor(1.0 if t == 0 else 0.0)
        acc, _, ta, geometry = temporal_accumulation(
            current, b["motion"], b["depth"], b["normal"], ta, geometry, reset, config
        )
        out = (acc * modulation)[0].numpy()
        dark = ref.mean(axis=0) < 0.1
        dark_max.append(float(out.mean(axis=0)[dark].max()) if dark.any() else 0.0)
        if t >= 4:
            rel.append(float(((out - ref) ** 2 / (ref**2 + 1e-2)).mean()))
            l1.append(float(np.abs(out / (1 + out) - ref / (1 + ref)).mean()))
            ratio.append(float(out.mean() / ref.mean()))
    return dark_max, float(np.mean(rel)), float(np.mean(l1)), float(np.mean(ratio))


def main(folders: list[str]) -> None:
    with torch.no_grad():
        for folder in folders:
            for per_tap in (1, 2, 3):
                dark, rel, l1, ratio = accumulate(folder, per_tap)
                print(
                    f"{folder:40s} per_tap {per_tap}: dark max "
                    + " ".join(f"{v:5.2f}" for v in dark)
                    + f" | relMSE {rel:.3f} tm-L1 {l1:.4f} brightness {ratio:.3f}"
                )


if __name__ == "__main__":
    if {"-h", "--help"} & set(sys.argv[1:]):
        print(__doc__)
        sys.exit(0)
    main(sys.argv[1:] or ["rtdenoise/assets/sequences/seq_000"])
