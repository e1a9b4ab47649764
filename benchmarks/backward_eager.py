"""An online model's backward pass + optimiser step, PyTorch eager vs ONNX Runtime (the fast
kernels the runtime picks), on the same synthetic frames in one run: the stages of
`denoise-bench stages` (export/stage_bench.py: torch's `stage` blocks; ORT's node profile,
every node assigned to a stage from the graph), without its slow ORT-portable pass. Medians
over the frames after a warm-up frame; each path runs its frames in turn, state fed back.

    python benchmarks/backward_eager.py --model demo:crossreg --size 1280x720 --frames 2
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from rtdenoise.export.stage_bench import STAGES, _ort_times, _torch_times  # noqa: E402
from rtdenoise.export.validate import synthetic_frames  # noqa: E402
from rtdenoise.models.checkpoint import load_checkpoint  # noqa: E402
from rtdenoise.runtime.session import resolve_model  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="demo:crossreg", help="demo:<family>")
    ap.add_argument("--size", default="1280x720", help="WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=2, help="timed frames (after one warm-up)")
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.size.split("x"))
    onnx_path = resolve_model(args.model)
    net, _ = load_checkpoint(onnx_path.with_suffix(".pt"))
    pad = net.pad_multiple
    h, w = -(-h // pad) * pad, -(-w // pad) * pad
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC, load {os.getloadavg()}, {os.cpu_count()} CPUs")
    print(f"# {' '.join(sys.argv)}")
    frames = synthetic_frames(net.inputs, args.frames + 1, h, w)
    torch_stages, torch_total = _torch_times(net.eval(), frames)
    ort_stages, ort_total = _ort_times(onnx_path.read_bytes(), frames, True, args.threads)
    print("\n| stage | PyTorch eager ms | ORT fast ms | eager / ORT |\n|---|---:|---:|---:|")
    for stage in STAGES:
        a, b = torch_stages.get(stage, 0.0), ort_stages.get(stage, 0.0)
        print(f"| {stage} | {a:.1f} | {b:.1f} | {a / b if b else float('nan'):.2f} |")
    print(f"| whole frame | {torch_total:.1f} | {ort_total:.1f} | {torch_total / ort_total:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
