"""Measure training-target options against a "true" high-spp reference (docs/data.md).

    python scripts/measure_references.py --out refs.json --size 64 --frames 4 \\
        --kinds room,glass,thin --true-spp 4096 --variant llvm_ad_rgb --threads 1

For each scene (kind k, seed --seed + j, frames of its camera path, cropped to --size), one
"true" reference at --true-spp (multijitter) and, with other seeds, each option:
- `ref N`: a high-spp reference at N spp (multijitter), N in --ref-spp;
- `n2n N`: an independent N-spp noisy render (independent sampler), N in --n2n-spp: a
  Noise2Noise target (an L2 loss on it is unbiased: E[(f - y)^2] = (f - E y)^2 + Var y);
- `oidn N`: an N-spp render denoised by Open Image Denoise high (albedo + normal), N in
  --oidn-spp, when pyoidn is installed.
Errors against the true reference: PSNR on tau-mapped images (pooled MSE) and relMSE (eps
0.01) on linear radiance, pooled over frames; render time per frame (this process's threads).
The true reference has its own noise: for an option at N spp the measured error is about
c (1/N + 1/true_spp), so the table also gives each `ref` row's error scaled to what it would
be against a noise-free reference. Prints a Markdown table; --out writes every number as JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _chw(img: np.ndarray) -> np.ndarray:
    return np.moveaxis(np.asarray(img, np.float64), -1, 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="JSON file with every number")
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--kinds", default="room,glass,thin")
    ap.add_argument("--seed", type=int, default=900_000, help="scene seeds --seed + j")
    ap.add_argument("--true-spp", type=int, default=4096)
    ap.add_argument("--ref-spp", default="256,512,1024")
    ap.add_argument("--n2n-spp", default="16,32,64")
    ap.add_argument("--oidn-spp", default="16,64")
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    from rtdenoise.datagen.cluster import set_render_threads
    from rtdenoise.datagen.variant import select_variant

    variant = select_variant(args.variant)
    set_render_threads(args.threads)
    import mitsuba as mi

    from rtdenoise.datagen.kinds import generate_scene
    from rtdenoise.datagen.paths import cameras_from_spec
    from rtdenoise.datagen.render import _AOVS, _aovs, _radiance, auto_exposure
    from rtdenoise.datagen.scene import build_scene
    from rtdenoise.datagen.seeds import derive_seed
    from rtdenoise.runtime.sequences.metrics import psnr_from_mse, tonemap

    try:
        import pyoidn
    except ImportError:
        pyoidn = None
    options = [("ref", int(n)) for n in args.ref_spp.split(",") if n]
    options += [("n2n", int(n)) for n in args.n2n_spp.split(",") if n]
    if pyoidn is not None:
        options += [("oidn", int(n)) for n in args.oidn_spp.split(",") if n]
    path = mi.load_dict({"type": "path", "max_depth": 6})
    aov = mi.load_dict({"type": "aov", "aovs": _AOVS})
    results: dict = {"settings": vars(args) | {"out": str(args.out), "variant": variant}}
    results["scenes"] = []
    for j, kind in enumerate(args.kinds.split(",")):
        seed = args.seed + j
        desc = generate_scene(seed, [kind])
        cams, cuts = cameras_from_spec(desc["camera"], args.frames, args.size, args.size)
        scene = build_scene(desc)
        pilot, _ = _radiance(mi, scene, path, cams[0], 16, derive_seed(seed, 2), "independent")
        exposure = auto_exposure(np.nan_to_num(pilot), 0.4)
        truth, t_true = [], 0.0
        for t, cam in enumerate(cams):
            t0 = time.perf_counter()
            img, _ = _radiance(mi, scene, path, cam, args.true_spp, derive_seed(seed, t, 0),
                               "multijitter")  # fmt: skip
            t_true += time.perf_counter() - t0
            truth.append(_chw(np.nan_to_num(img) * exposure))
        row = {"kind": kind, "seed": seed, "cuts": cuts, "true_s_per_frame": t_true / len(cams)}
        print(f"{kind} (seed {seed}): true {args.true_spp} spp {row['true_s_per_frame']:.1f} s"
              "/frame", flush=True)  # fmt: skip
        for name, spp in options:
            sq, rel, secs = [], [], 0.0
            for t, cam in enumerate(cams):
                s = derive_seed(seed, t, 1 + spp + {"ref": 0, "n2n": 1, "oidn": 2}[name])
                sampler = "multijitter" if name == "ref" else "independent"
                t0 = time.perf_counter()
                img, _ = _radiance(mi, scene, path, cam, spp, s, sampler)
                img = np.maximum(np.nan_to_num(img) * exposure, 0.0)
                if name == "oidn":
                    a = _aovs(mi, scene, aov, cam)
                    alb = np.clip(np.nan_to_num(a["albedo"]), 0, 1).astype(np.float32)
                    nrm = np.nan_to_num(a["nn"]).astype(np.float32)
                    img = pyoidn.denoise(img.astype(np.float32), alb, nrm, hdr=True,
                                         quality="high")  # fmt: skip
                secs += time.perf_counter() - t0
                x, y = _chw(img), truth[t]
                sq.append(np.mean((tonemap(x) - tonemap(y)) ** 2))
                rel.append(np.mean((x - y) ** 2 / (y * y + 1e-2)))
            mse, relmse = float(np.mean(sq)), float(np.mean(rel))
            row[f"{name} {spp}"] = {"psnr": psnr_from_mse(mse), "relmse": relmse,
                                    "s_per_frame": secs / len(cams)}  # fmt: skip
            print(f"  {name} {spp:5d} spp: PSNR {psnr_from_mse(mse):6.2f} dB, relMSE "
                  f"{relmse:.5f}, {secs / len(cams):.2f} s/frame", flush=True)  # fmt: skip
        results["scenes"].append(row)
    print(_table(results, options, args.true_spp))
    if args.out is not None:
        args.out.write_text(json.dumps(results, indent=1) + "\n")


def _table(results: dict, options: list[tuple[str, int]], true_spp: int) -> str:
    """Markdown: one row per option, PSNR / relMSE per scene, mean, seconds per frame."""
    scenes = results["scenes"]
    head = " | ".join(f"{s['kind']} PSNR / relMSE" for s in scenes)
    lines = [f"| target | {head} | mean PSNR | s/frame (mean) |", "|---" * (len(scenes) + 3) + "|"]
    for name, spp in options:
        key = f"{name} {spp}"
        cells = [f"{s[key]['psnr']:.2f} / {s[key]['relmse']:.4f}" for s in scenes]
        mean_psnr = float(np.mean([s[key]["psnr"] for s in scenes]))
        secs = float(np.mean([s[key]["s_per_frame"] for s in scenes]))
        lines.append(f"| {key} spp | {' | '.join(cells)} | {mean_psnr:.2f} | {secs:.2f} |")
    secs = float(np.mean([s["true_s_per_frame"] for s in scenes]))
    lines.append(f"| (true reference: {true_spp} spp) | " + " | ".join("-" for _ in scenes)
                 + f" | - | {secs:.2f} |")  # fmt: skip
    return "\n".join(lines)


if __name__ == "__main__":
    main()
