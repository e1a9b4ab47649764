"""Markdown tables from `denoise-bench compare --json` files, for benchmarks/README.md.

    python benchmarks/compare_table.py run.json [more.json ...]

Per file: ms per frame (median, min-max) at each size with the ratio to OIDN high and fast at
that size, ns per pixel and its spread over the sizes (largest / smallest), and quality
(PSNR, SSIM, TRMAE) on the file's sequences; then, for each model timed in PyTorch eager too,
ORT fast's speed-up over it.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def _ms(s: dict) -> str:
    return f"{s['median_ms']:.1f} ({s['min_ms']:.1f}-{s['max_ms']:.1f})"


def table(result: dict) -> str:
    rows = result["speed"]
    sizes = [f"{w}x{h}" for h, w in (r["size"] for r in rows)]
    names = list(result["quality"])
    lines = [
        f"{result['machine']}, threads {result.get('threads') or 'default'}, "
        "timed frames per size "
        + ", ".join(
            f"{s} {r.get('repeats', result['repeats'])}" for s, r in zip(sizes, rows, strict=True)
        )
        + " after a warm-up frame, interleaved; "
        f"quality on {', '.join(result['sequences'])}",
        "",
        "| denoiser | " + " | ".join(f"{s} ms" for s in sizes) + " | x OIDN high / fast at "
        f"{sizes[min(1, len(sizes) - 1)]} | ns/px | ns/px max/min | PSNR dB | SSIM | TRMAE |",
        "|---|" + "---:|" * (len(sizes) + 6),
    ]
    ref = rows[min(1, len(rows) - 1)]["summary"]
    for name in names:
        summ = [r["summary"][name] for r in rows]
        ns = [s["ns_per_pixel"] for s in summ]
        ratio = " / ".join(
            f"{summ[min(1, len(summ) - 1)]['median_ms'] / ref[o]['median_ms']:.2f}"
            if o in ref
            else "-"
            for o in ("OIDN high", "OIDN fast")
        )
        q = result["quality"][name]["mean"]
        lines.append(
            f"| {name} | "
            + " | ".join(_ms(s) for s in summ)
            + f" | {ratio} | {ns[min(1, len(ns) - 1)]:.0f} | {max(ns) / min(ns):.2f} | "
            f"{q['psnr']:.2f} | {q['ssim']:.4f} | {q['trmae']:.4f} |"
        )
    n = result["noisy"]["mean"]
    cells = ["noisy input", *[""] * (len(sizes) + 3), f"{n['psnr']:.2f}", f"{n['ssim']:.4f}"]
    lines.append("| " + " | ".join([*cells, f"{n['trmae']:.4f}"]) + " |")
    eager = [x for x in names if x.endswith(")") and " (PyTorch " in x]
    if eager:
        heads = " | ".join(f"ORT fast vs PyTorch eager, {s}" for s in sizes)
        lines += ["", f"| model | {heads} |"]
        lines.append("|---|" + "---:|" * len(sizes))
        for e in eager:
            base = e.split(" (PyTorch ")[0]
            speedups = [
                r["summary"][e]["median_ms"] / r["summary"][base]["median_ms"] for r in rows
            ]
            lines.append(f"| {base} | " + " | ".join(f"{x:.2f}x" for x in speedups) + " |")
    return "\n".join(lines)


def main(paths: list[str]) -> None:
    for path in paths:
        print(table(json.loads(Path(path).read_text())))
        print()


if __name__ == "__main__":
    main(sys.argv[1:])
