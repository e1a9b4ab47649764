"""Random-init checkpoints of the light families at larger widths, to time against OIDN fast:
how much capacity fits in OIDN fast's time per 720p frame (issue: quality, retrained models).

Writes one checkpoint per candidate config into OUT (weights random: only the time means
anything), then prints the `denoise-bench compare` command that times them beside the shipped
demos and OIDN in one interleaved run:

    python benchmarks/capacity_budget.py /tmp/capacity
    denoise-bench compare $(ls /tmp/capacity/*.pt) demo:afn demo:wskp demo:nbg \\
        --oidn fast --oidn high --size 1280x720 --repeats 5 --json capacity.json
"""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from rtdenoise.models import build_model, parameter_count, save_checkpoint

CANDIDATES = {
    "afn-w24": ("afn", {"widths": [24, 18, 24, 36, 48]}),
    "afn-w32": ("afn", {"widths": [32, 24, 32, 48, 64]}),
    "wskp-w24x3": ("wskp", {"width": 24, "layers": 3}),
    "wskp-w32x3": ("wskp", {"width": 32, "layers": 3}),
    "wskp-w24x4": ("wskp", {"width": 24, "layers": 4}),
    "wskp-w24x6": ("wskp", {"width": 24, "layers": 6}),
    "wskp-w32x6": ("wskp", {"width": 32, "layers": 6}),
    "nbg-h40": ("nbg", {"hidden": 40}),
    "nbg-h64": ("nbg", {"hidden": 64}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, (family, config) in CANDIDATES.items():
        model = build_model(family, config)
        path = save_checkpoint(args.out / f"{name}.pt", model, {"candidate": name})
        paths.append(str(path))
        print(f"{name}: {family} {config}, {parameter_count(model):,} parameters")
    demos = ["demo:afn", "demo:wskp", "demo:nbg"]
    timing = ["--oidn", "fast", "--oidn", "high", "--size", "1280x720", "--repeats", "5"]
    command = ["denoise-bench", "compare", *paths, *demos, *timing]
    print(shlex.join(command))


if __name__ == "__main__":
    main()
