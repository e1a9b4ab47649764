"""Does Choi24's online learning pay? demo:crossreg learning vs frozen, frame by frame.

Runs the crossreg checkpoint (its weights are the initial theta) in PyTorch eager over each
sequence twice from the same init: learning (one Adam step per frame, as shipped) and frozen
(`freeze` = 1 on every frame: the init's output). A camera cut restarts the history and keeps
the learning (state `keep` = 1), as `Denoiser.reset()` does. Config overrides are variants
(`--variant NAME=JSON`, e.g. `lr3=\'{"lr": 3e-3}\'`), each run both ways from the same weights.
Prints per sequence the tau-PSNR pooled over the frames from --skip on, learning minus frozen,
and the learning curve in blocks of --block frames:

    python benchmarks/online_gain.py /work/data/long/seq_000 validation/seq_00{0..7} \\
        --variant default='{}' --variant lr3e-3='{"lr": 3e-3}' --json online_gain.json

`--oracle` is a diagnostic: the online loss's labels (the other buffer's pilot, the warped
previous pilots) are replaced by the reference itself, log1p(ref), in eq. (12)'s relative form.
What learning gains then is what any self-supervised label could buy at most with this
optimiser (one Adam step per frame at the config's lr) on these frames.

`--ort demo:crossreg` (or an .onnx) runs the exported model in ONNX Runtime instead, learning
and frozen from its shipped init (the numbers issue 25 asks for; no variants):

    python benchmarks/online_gain.py validation/long_000 validation/seq_00{0..7} --ort demo:crossreg

`--steps-per-frame K` takes K Adam steps on each frame's loss instead of one (the frame is shown
from the first, as shipped; the K - 1 more re-run it from the same history and keep only theta
and Adam's moments): what more update per frame buys, with either label.
"""

from __future__ import annotations

import argparse
import json
import time
import types
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from rtdenoise.models.checkpoint import read_checkpoint
from rtdenoise.models.data import load_sequence
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.sequences.metrics import mse_tonemapped, psnr_from_mse
from rtdenoise.shipped import demo_model

# config keys a frozen run's output does not depend on (Adam's and the online loss's)
LEARNING_ONLY = (
    "lr",
    "beta1",
    "beta2",
    "adam_eps",
    "loss_eps",
    "temporal_pairing",
    "temporal_screening",
    "temporal_loss_weight",
)


def oracle_loss(self, hat_a, hat_b, pilot_a, pilot_b, prev_a, prev_b, has_history):
    """eq. (12)'s relative form with the reference (self.oracle_label) as both buffers' label."""
    label, eps = self.oracle_label, self.cfg.loss_eps
    return (0.5 * ((hat_a - label) ** 2 + (hat_b - label) ** 2) / (label * label + eps)).mean()


LEARNED_STATE = ("theta", "adam_m", "adam_v", "adam_t")


def outputs(
    model, seq, learn: bool = True, oracle: bool = False, steps_per_frame: int = 1
) -> Iterator[np.ndarray]:
    """`model`'s output (C, H, W) on each frame of `seq`, learning or frozen, its state carried
    and a cut restarting the history, not the learning; with `oracle`, the online update learns
    from each frame's reference (`oracle_loss`); learning takes `steps_per_frame` Adam steps on
    each frame."""
    if oracle:
        model.online_loss = types.MethodType(oracle_loss, model)
    n_frames = seq.reference.shape[0]
    h, w = seq.reference.shape[-2:]
    state = model.initial_state(1, h, w)
    cuts = set(seq.cuts)
    with torch.no_grad():
        for t in range(n_frames):
            buffers = {k: torch.from_numpy(v[t][None]) for k, v in seq.buffers.items()}
            first = t == 0 or t in cuts
            if oracle:
                ref = torch.from_numpy(np.ascontiguousarray(seq.reference[t][None]))
                model.oracle_label = torch.log1p(torch.clamp(ref, min=0.0))
            state["freeze"] = torch.full_like(state["freeze"], 0.0 if learn else 1.0)
            state["keep"] = torch.full_like(state["keep"], 0.0 if t == 0 else 1.0)
            reset = torch.tensor(1.0 if first else 0.0)
            out, new_state = model(buffers, state, reset)
            for _ in range(steps_per_frame - 1 if learn else 0):
                _, again = model(
                    buffers, {**state, **{k: new_state[k] for k in LEARNED_STATE}}, reset
                )
                new_state = {**new_state, **{k: again[k] for k in LEARNED_STATE}}
            state = new_state
            yield out[0].numpy()


def run(model, seq, learn: bool, oracle: bool = False, steps_per_frame: int = 1) -> list[float]:
    """Per-frame tonemapped MSE of `model` over `seq` (`outputs`)."""
    frames = outputs(model, seq, learn, oracle, steps_per_frame)
    return [mse_tonemapped(out, ref) for out, ref in zip(frames, seq.reference, strict=True)]


def run_ort(onnx: str, seq, learn: bool) -> list[float]:
    """Per-frame tonemapped MSE of the exported model in ONNX Runtime (`Denoiser`, the fast
    path), learning or frozen from its shipped init, a cut restarting the history only."""
    from rtdenoise.runtime import Denoiser

    den = Denoiser(onnx, learn=learn)
    cuts = set(seq.cuts)
    mses = []
    for t in range(seq.reference.shape[0]):
        frame = {k: v[t] for k, v in seq.buffers.items()}
        mses.append(mse_tonemapped(den.process(frame, reset=t in cuts), seq.reference[t]))
    return mses


def pooled(mses: list[float], skip: int) -> float:
    return psnr_from_mse(float(np.mean(mses[skip:])))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequences", nargs="+", type=Path)
    ap.add_argument("--checkpoint", default=None, help="crossreg .pt (default: demo:crossreg)")
    ap.add_argument("--variant", action="append", default=[], help="NAME=JSON config overrides")
    ap.add_argument("--skip", type=int, default=8, help="score frames from this one on")
    ap.add_argument("--block", type=int, default=8, help="learning curve in blocks of N frames")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument(
        "--oracle", action="store_true", help="learn from the reference (a diagnostic bound)"
    )
    ap.add_argument(
        "--steps-per-frame", type=int, default=1, help="Adam steps on each frame's loss"
    )
    ap.add_argument(
        "--ort",
        default=None,
        help="an exported .onnx (or demo:crossreg) run in ONNX Runtime instead: learning vs "
        "frozen from its shipped init (no variants)",
    )
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.ort:
        return main_ort(args)
    if args.threads:
        torch.set_num_threads(args.threads)
    ckpt = read_checkpoint(args.checkpoint or demo_model("crossreg", ".pt"))
    variants = dict(v.split("=", 1) for v in args.variant) or {"default": "{}"}
    base = build_model("crossreg", ckpt["config"])
    seqs = [load_sequence(p, base.inputs) for p in args.sequences]
    results: dict = {}
    frozen_runs: dict = {}  # the frozen run does not read Adam's settings: one per other config
    for name, overrides in variants.items():
        config = {**ckpt["config"], **json.loads(overrides)}
        model = build_model("crossreg", config)
        model.load_state_dict(ckpt["state_dict"])
        model.eval()
        frozen_key = json.dumps(
            {k: v for k, v in config.items() if k not in LEARNING_ONLY}, sort_keys=True
        )
        results[name] = {}
        for index, seq in enumerate(seqs):
            t0 = time.perf_counter()
            learn = run(model, seq, True, args.oracle, args.steps_per_frame)
            key = (frozen_key, index)
            if key not in frozen_runs:
                frozen_runs[key] = run(model, seq, False)
            frozen = frozen_runs[key]
            row = {
                "frames": len(learn),
                "learning": pooled(learn, args.skip),
                "frozen": pooled(frozen, args.skip),
                "curve_learning": [
                    pooled(learn[i : i + args.block], 0) for i in range(0, len(learn), args.block)
                ],
                "curve_frozen": [
                    pooled(frozen[i : i + args.block], 0) for i in range(0, len(frozen), args.block)
                ],
            }
            row["gain"] = row["learning"] - row["frozen"]
            results[name][seq.name] = row
            curve = " ".join(
                f"{a - b:+.2f}"
                for a, b in zip(row["curve_learning"], row["curve_frozen"], strict=True)
            )
            print(
                f"{name:12s} {seq.name:10s} {row['frames']:3d} frames: learning "
                f"{row['learning']:.2f} frozen {row['frozen']:.2f} dB (frames >= {args.skip}), "
                f"gain {row['gain']:+.2f}; per {args.block} frames {curve} "
                f"({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )
        gains = [r["gain"] for r in results[name].values()]
        print(f"{name:12s} mean gain {np.mean(gains):+.3f} dB over {len(gains)} sequences")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


def main_ort(args: argparse.Namespace) -> int:
    """`--ort`: each sequence learning and frozen in ONNX Runtime; the gain and the pooled
    tau-PSNR of the frames from --skip on."""
    results = {}
    for path in args.sequences:
        seq = load_sequence(path, build_model("crossreg", {}).inputs)
        learn, frozen = run_ort(args.ort, seq, True), run_ort(args.ort, seq, False)
        row = {"learning": pooled(learn, args.skip), "frozen": pooled(frozen, args.skip)}
        row["gain"] = row["learning"] - row["frozen"]
        results[seq.name] = row
        print(
            f"ort {seq.name:10s} learning {row['learning']:.2f} frozen {row['frozen']:.2f} dB "
            f"(frames >= {args.skip}), gain {row['gain']:+.2f}",
            flush=True,
        )
    gains = [r["gain"] for r in results.values()]
    print(f"ort mean gain {np.mean(gains):+.3f} dB, least {min(gains):+.3f}, {len(gains)} seqs")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
