"""What a gain estimated online from the two noisy buffers would do to crossreg's frozen
output (issue 25, item 1: what an update could learn that Choi24's does not).

Choi24 regresses and filters log1p values, so its output is darker than the reference where a
pixel is noisy (benchmarks/README.md, "The log domain's darkening"). Its online loss compares
log values too, whose labels are biased the same way, so the update cannot see the darkening.
Linear radiance labels are unbiased: the other buffer's 1-spp colour has the reference as its
mean. This runs demo:crossreg (or --checkpoint) frozen over each sequence and rescales each
frame's output by g_t: one gain per frame (or per tile x tile block with --tile), the weighted
least-squares gain of the output against the mean of the two noisy buffers (weights
1 / (output^2 + eps): relative; `--eps inf`: plain L2), averaged over frames with weight `beta`
on the past (EMA). Prints tau-PSNR pooled over frames from --skip on: frozen, each (eps,
beta), and the oracle's gain (least squares against the reference, per frame or tile).

    python benchmarks/gain_bound.py validation/long_000 validation/seq_00{0..7} \\
        --eps inf --eps 1e-2 --beta 0 --beta 0.95
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from online_gain import outputs

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.data import load_sequence
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.sequences.metrics import mse_tonemapped, psnr_from_mse
from rtdenoise.shipped import demo_model


def gain(out: np.ndarray, label: np.ndarray, eps: float, tile: int = 0) -> np.ndarray:
    """argmin_g sum w (g out - label)^2 with w = 1 / (out^2 + eps) (w = 1 for eps = inf),
    over the whole frame (tile 0) or per tile x tile block; as an (H, W) map of gains."""
    w = np.ones_like(out) if np.isinf(eps) else 1.0 / (out * out + eps)
    num, den = (w * out * label).sum(0), (w * out * out).sum(0)  # (H, W)
    h, wd = num.shape
    t = tile or max(h, wd)
    ny, nx = -(-h // t), -(-wd // t)
    pad = ((0, ny * t - h), (0, nx * t - wd))
    blocks = [np.pad(a, pad).reshape(ny, t, nx, t).sum((1, 3)) for a in (num, den)]
    g = blocks[0] / np.maximum(blocks[1], 1e-12)
    return np.repeat(np.repeat(g, t, 0), t, 1)[:h, :wd]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--checkpoint", default=None, help="crossreg .pt (default: demo:crossreg)")
    ap.add_argument("--eps", action="append", type=float, default=None)
    ap.add_argument("--beta", action="append", type=float, default=None)
    ap.add_argument("--tile", type=int, default=0, help="gains per tile (0: one per frame)")
    ap.add_argument("--skip", type=int, default=8, help="score frames from this one on")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    ckpt = read_checkpoint(args.checkpoint or demo_model("crossreg", ".pt"))
    model = build_model("crossreg", ckpt["config"])
    model.load_state_dict(ckpt["state_dict"])
    model.eval()
    settings = [(e, b) for e in args.eps or [float("inf"), 1e-2] for b in args.beta or [0.0]]
    names = ["frozen", *(f"eps {e:g} beta {b:g}" for e, b in settings), "oracle gain"]
    print("| sequence | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(names))
    for path in args.sequences:
        seq = load_sequence(path, model.inputs)
        frames = list(outputs(model, seq, learn=False))
        ref, noisy = seq.reference, 0.5 * (seq.buffers["color"] + seq.buffers["color_b"])

        def pooled(scales: list, frames=frames, ref=ref) -> float:
            mses = [mse_tonemapped(o * s, r) for o, s, r in zip(frames, scales, ref, strict=True)]
            return psnr_from_mse(float(np.mean(mses[args.skip :])))

        row = [pooled([1.0] * len(frames))]
        for eps, beta in settings:
            g, scales = None, []
            for o, label in zip(frames, noisy, strict=True):
                now = gain(o, label, eps, args.tile)
                g = now if g is None else beta * g + (1 - beta) * now
                scales.append(g)
            row.append(pooled(scales))
        row.append(
            pooled([gain(o, r, float("inf"), args.tile) for o, r in zip(frames, ref, strict=True)])
        )
        print(f"| {path.name} | " + " | ".join(f"{v:.2f}" for v in row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
