"""Contact sheet of the scene kinds: frame 0 of a few seeds per kind (tone-mapped PNG).

    python scripts/preview_kinds.py preview.png --seeds 3 --size 96 --spp 64

Rows are kinds, columns seeds 0..N-1 (the scene `kinds.generate_scene(seed, [kind])` draws).
Needs the data extra (mitsuba) and matplotlib (its PNG writer).
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="PNG file to write")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--size", type=int, default=96)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--kinds", default=None, help="comma-separated (default: all)")
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()

    from rtdenoise.datagen.cluster import set_render_threads
    from rtdenoise.datagen.variant import select_variant

    select_variant(args.variant)
    set_render_threads(args.threads)
    import matplotlib.pyplot as plt
    import mitsuba as mi

    from rtdenoise.datagen.kinds import KINDS, generate_scene
    from rtdenoise.datagen.paths import cameras_from_spec
    from rtdenoise.datagen.render import _radiance, auto_exposure
    from rtdenoise.datagen.scene import build_scene
    from rtdenoise.datagen.validate import tonemap

    kinds = args.kinds.split(",") if args.kinds else [k for k in KINDS if k != "legacy"]
    path = mi.load_dict({"type": "path", "max_depth": 6})
    rows = []
    for kind in kinds:
        row = []
        for seed in range(args.seeds):
            desc = generate_scene(seed, [kind])
            cam = cameras_from_spec(desc["camera"], 1, args.size, args.size)[0][0]
            img, _ = _radiance(mi, build_scene(desc), path, cam, args.spp, seed, "independent")
            img = np.nan_to_num(img)
            row.append(tonemap(img * auto_exposure(img, 0.4)))
        rows.append(np.concatenate(row, axis=1))
        print(kind, flush=True)
    sheet = np.clip(np.concatenate(rows, axis=0), 0, 1)
    plt.imsave(args.out, sheet)
    print(f"{args.out}: rows {', '.join(kinds)}")


if __name__ == "__main__":
    main()
