"""Per-sequence quality from `denoise-bench compare --json` files: each denoiser's mean
metrics and every (sequence, metric) where it is worse than the noisy input.

    python benchmarks/worse_than_input.py validation.json committed.json

Issue 31 asks that no shipped model be worse than the noisy input on any reported metric
(PSNR, SSIM, SMAPE, relMSE) on any committed or validation sequence; this lists where one is.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "smape": False, "relmse": False}


def worse_than_input(result: dict) -> dict[str, list[str]]:
    """Denoiser name -> ["seq_002 relmse 9.46 > 3.47", ...]."""
    noisy = result["noisy"]["sequences"]
    found: dict[str, list[str]] = {}
    for name, quality in result["quality"].items():
        rows = []
        for seq, metrics in quality["sequences"].items():
            for metric, higher in HIGHER_IS_BETTER.items():
                ours, theirs = metrics[metric], noisy[seq][metric]
                if (ours < theirs) if higher else (ours > theirs):
                    sign = "<" if higher else ">"
                    rows.append(f"{seq} {metric} {ours:.4g} {sign} {theirs:.4g}")
        found[name] = rows
    return found


def report(path: Path) -> str:
    result = json.loads(path.read_text())
    worse = worse_than_input(result)
    lines = [
        f"{path.name}: {', '.join(result['sequences'])}",
        "",
        "| denoiser | PSNR | SSIM | SMAPE | relMSE | TRMAE | worse than the input |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for name, quality in [("noisy input", result["noisy"]), *result["quality"].items()]:
        m = quality["mean"]
        where = "-" if name == "noisy input" else "; ".join(worse[name]) or "nowhere"
        lines.append(
            f"| {name} | {m['psnr']:.2f} | {m['ssim']:.4f} | {m['smape']:.4f} | "
            f"{m['relmse']:.3f} | {m['trmae']:.3f} | {where} |"
        )
    return "\n".join(lines)


def main(paths: list[str]) -> None:
    print("\n\n".join(report(Path(p)) for p in paths))


if __name__ == "__main__":
    main(sys.argv[1:])
