"""demo:crossreg's weights under config overrides, online learning on as shipped (PyTorch eager,
one thread; `online_gain.outputs`): every metric on the committed and the validation sequences,
and where the output is worse than the noisy input. Each argument is one variant, a JSON object
of config overrides (`{}` = the shipped config):

    python benchmarks/crossreg_variants.py '{}' '{"history_clamp": 0}' '{"history_clamp": 2}'
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch
from online_gain import outputs

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.data import load_sequence
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.sequences.metrics import SequenceMetrics
from rtdenoise.shipped import demo_model, sample_sequences

VALIDATION = Path(__file__).resolve().parents[1] / "validation"
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "smape": False, "relmse": False}


def scores(model, seq) -> tuple[dict, dict]:
    """Summaries of the output and of the noisy input over one sequence (learning on)."""
    out_m, in_m = SequenceMetrics(), SequenceMetrics()
    for out, color, ref in zip(
        outputs(model, seq), seq.buffers["color"], seq.reference, strict=True
    ):
        out_m.add(out, ref)
        in_m.add(color, ref)
    return out_m.summary(), in_m.summary()


def main(argv: list[str]) -> None:
    torch.set_num_threads(1)
    ckpt = read_checkpoint(demo_model("crossreg", ".pt"))
    inputs = build_model("crossreg", ckpt["config"]).inputs
    names = [(f"committed seq_{i:03d}", s) for i, s in enumerate(sample_sequences())]
    names += [(f"validation seq_{i:03d}", VALIDATION / f"seq_{i:03d}") for i in range(8)]
    data = {name: load_sequence(folder, inputs) for name, folder in names}
    for spec in argv or ["{}"]:
        model = build_model("crossreg", {**ckpt["config"], **json.loads(spec)})
        model.load_state_dict(ckpt["state_dict"])
        rows = {name: scores(model, seq) for name, seq in data.items()}
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
