"""Where a model loses to OIDN high: PSNR (tau-mapped, pooled) on the validation frames without
history (the first, and the first after a cut) and on those with history, per sequence.

    python benchmarks/history_split.py demo:nbg [--sequence validation/seq_003 ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from rtdenoise.runtime.denoiser import Denoiser
from rtdenoise.runtime.sequences.frames import (
    find_frames,
    match_references,
    read_frame,
    read_reference,
)
from rtdenoise.runtime.sequences.metrics import mse_tonemapped, psnr_from_mse
from rtdenoise.runtime.sequences.samples import sample_features_of, samples_from_buffers

VALIDATION = Path(__file__).resolve().parents[1] / "validation"


def oidn_high(frame: dict) -> np.ndarray:
    """pyoidn 2.5's RT filter, HDR, albedo + normal, quality high (CHW in and out)."""
    import pyoidn

    hwc = lambda x: np.ascontiguousarray(np.transpose(x, (1, 2, 0)), dtype=np.float32)  # noqa: E731
    out = pyoidn.denoise(
        hwc(frame["color"]), hwc(frame["albedo"]), hwc(frame["normal"]), hdr=True, quality="high"
    )
    return np.transpose(out, (2, 0, 1))


def split(model: str, folder: Path) -> str:
    paths = find_frames(folder)
    frames = [read_frame(p).buffers for p in paths]
    refs = [read_reference(r) for r in match_references(paths)]
    cuts = set(json.loads((folder / "meta.json").read_text()).get("cuts") or [])
    denoiser = Denoiser(model)
    if "samples" in denoiser.required_buffers:
        features = sample_features_of(denoiser.config)
        frames = [f | {"samples": samples_from_buffers(f, features)} for f in frames]
    ours = np.array(
        [
            mse_tonemapped(denoiser.process(f, reset=t in cuts), r)
            for t, (f, r) in enumerate(zip(frames, refs, strict=True))
        ]
    )
    oidn = np.array([mse_tonemapped(oidn_high(f), r) for f, r in zip(frames, refs, strict=True)])
    fresh = np.array([t == 0 or t in cuts for t in range(len(frames))])

    def psnr(m: np.ndarray) -> float:
        return psnr_from_mse(float(np.mean(m)))

    def part(mask: np.ndarray) -> str:
        a, b = psnr(ours[mask]), psnr(oidn[mask])
        return f"{a:.2f} vs {b:.2f} ({a - b:+.2f})"

    return (
        f"{folder.name}: all {psnr(ours) - psnr(oidn):+.2f} dB | without history {part(fresh)}"
        f" | with history {part(~fresh)} | share of the model's error without history"
        f" {ours[fresh].sum() / ours.sum():.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("model")
    ap.add_argument("--sequence", type=Path, action="append")
    args = ap.parse_args()
    for folder in args.sequence or sorted(VALIDATION.glob("seq_*")):
        print(split(args.model, folder), flush=True)


if __name__ == "__main__":
    main()
