"""Summarise a rendered data set: complete / partial sequences, kinds, cuts, redraws, and the
sequences that look wrong (black: exposure at its clamp; camera against a shape).

    python scripts/dataset_report.py /work/data/train_v2 [--warp N] [--delete-bad]

--warp N also runs the motion-vector warp check (datagen/validate.py) on the first N complete
sequences. --delete-bad removes the wrong-looking ones, so that a rerun of the job renders them
again (with the shot redraw of datagen/render.py).
"""

from __future__ import annotations

import argparse
import json
import shutil
from collections import Counter
from pathlib import Path

import numpy as np

from rtdenoise.datagen.render import NEAR_DEPTH, NEAR_FRACTION
from rtdenoise.datagen.validate import warp_gain_db
from rtdenoise.runtime.sequences.exr import read_exr

EXPOSURE_CLAMP = 1e3  # render.auto_exposure's upper bound: a black pilot


def problem(seq: Path, meta: dict) -> str | None:
    """Why a complete sequence looks wrong (None: fine)."""
    if meta["exposure"] >= EXPOSURE_CLAMP:
        return "exposure at its clamp (black frame 0)"
    for t in range(meta["frame_count"]):
        d = read_exr(seq / f"frame_{t:04d}.exr")["depth.Z"]
        if float(((d < NEAR_DEPTH) & (d < 1e4)).mean()) > NEAR_FRACTION:
            return f"frame {t}: camera against a shape"
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--warp", type=int, default=0)
    ap.add_argument("--delete-bad", action="store_true")
    args = ap.parse_args()
    complete, partial, kinds, bad, gains = [], [], Counter(), [], []
    cuts = redraws = 0
    for seq in sorted(args.folder.glob("seq_*")):
        if not (seq / "meta.json").is_file():
            partial.append(seq.name)
            continue
        meta = json.loads((seq / "meta.json").read_text())
        complete.append(seq.name)
        kinds[meta.get("kind", "?")] += 1
        cuts += bool(meta.get("cuts"))
        redraws += bool(meta.get("redraws"))
        why = problem(seq, meta)
        if why:
            bad.append((seq, why))
        elif len(gains) < args.warp:
            gains.append(warp_gain_db(seq))
            if not np.isfinite(gains[-1]):  # no frame with valid pixels: nothing to score
                gains.pop()
            elif gains[-1] < -1.0:  # a still camera scores 0: below it the warp is wrong
                bad.append((seq, f"motion vectors warp worse than none ({gains[-1]:.1f} dB)"))
    print(f"{args.folder}: {len(complete)} complete, {len(partial)} in progress {partial}")
    print("kinds: " + ", ".join(f"{k} {n}" for k, n in kinds.most_common()))
    print(f"with a cut: {cuts}; shot drawn again: {redraws}")
    if gains:
        print(f"warp gain over {len(gains)} sequences: min {min(gains):.1f} dB, "
              f"median {float(np.median(gains)):.1f} dB")  # fmt: skip
    for seq, why in bad:
        print(f"looks wrong: {seq.name}: {why}" + (" (deleted)" if args.delete_bad else ""))
        if args.delete_bad:
            shutil.rmtree(seq)


if __name__ == "__main__":
    main()
