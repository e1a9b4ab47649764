"""Where a frame's time goes: the convolutions vs the rest, PyTorch eager vs ONNX Runtime.

Per model and size, one run, frames interleaved (eager, ORT, eager, ORT ..., 100 ms pause
after each, as `denoise-bench compare` times them), state carried, after a warm-up frame:

- PyTorch eager, the checkpoint's deployed form (what `compare --eager` times): the whole
  frame, and the time inside its `nn.Conv2d` modules (forward hooks around each call);
- ONNX Runtime with the fast kernels (`Denoiser`, the demo's shipped file or the checkpoint
  exported in memory): the whole frame, and its profiler's time in the nodes that compute the
  network's convolutions (Conv, its NCHWc form, the MatMul heads and ConvTranspose
  interleaves the export writes for some convs: export/matmul_heads.py, export/phase_split.py).

Prints medians per frame and the ratio `eager frame / ORT frame` next to its ceiling
`eager frame / ORT convs` (what ORT would reach if everything but its convs took no time).
Both libraries run as the CLIs run them: OMP_WAIT_POLICY=PASSIVE, `tune_allocator`.

    python benchmarks/conv_share.py --model demo:afn --model demo:wskp --model demo:nbg \\
        --size 1280x720 --frames 7
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch's and numba's OpenMP start

import onnxruntime as ort  # noqa: E402
import torch  # noqa: E402
from torch import nn  # noqa: E402

from rtdenoise.cli.export import resolve_checkpoint  # noqa: E402
from rtdenoise.export.deploy import to_deploy  # noqa: E402
from rtdenoise.export.onnx_export import export_model  # noqa: E402
from rtdenoise.export.stage_bench import node_ms_per_run  # noqa: E402
from rtdenoise.models.checkpoint import load_checkpoint  # noqa: E402
from rtdenoise.models.frame_loop import FrameLoop  # noqa: E402
from rtdenoise.runtime import denoiser as denoiser_module  # noqa: E402
from rtdenoise.runtime.memory import tune_allocator  # noqa: E402
from rtdenoise.runtime.sequences.synthetic import synthetic_frames  # noqa: E402

CONV_NODES = ("Conv", "FusedConv", "MatMul", "ConvTranspose")
PAUSE_S = 0.1


class ConvTimer:
    """Milliseconds spent inside a module tree's nn.Conv2d calls since the last `take()`."""

    def __init__(self, model: nn.Module) -> None:
        self.ms = 0.0
        self._start: dict[int, float] = {}
        for m in model.modules():
            if isinstance(m, nn.Conv2d):
                m.register_forward_pre_hook(self._enter)
                m.register_forward_hook(self._leave)

    def _enter(self, module, _inputs) -> None:
        self._start[id(module)] = time.perf_counter()

    def _leave(self, module, _inputs, _output) -> None:
        self.ms += (time.perf_counter() - self._start.pop(id(module))) * 1e3

    def take(self) -> float:
        ms, self.ms = self.ms, 0.0
        return ms


def profiled_denoiser(model: str | bytes, prefix: str) -> denoiser_module.Denoiser:
    """A default `Denoiser` whose session writes ORT's node profile under `prefix`."""
    plain = denoiser_module.ort.SessionOptions

    def options() -> ort.SessionOptions:
        so = plain()
        so.enable_profiling = True
        so.profile_file_prefix = prefix
        return so

    denoiser_module.ort.SessionOptions = options
    try:
        return denoiser_module.Denoiser(model)
    finally:
        denoiser_module.ort.SessionOptions = plain


def measure(spec: str, h: int, w: int, frames: int) -> dict[str, float]:
    net, _ = load_checkpoint(resolve_checkpoint(spec))
    deployed = to_deploy(net.eval(), inplace=True).requires_grad_(False)
    timer = ConvTimer(deployed)
    loop = FrameLoop(deployed)
    source = spec if spec.startswith("demo:") else export_model(net).SerializeToString()
    den = profiled_denoiser(source, os.path.join(tempfile.mkdtemp(), "ort"))
    seq = synthetic_frames(den.required_buffers, 4, h, w)
    tensors = [{k: torch.from_numpy(v) for k, v in f.items()} for f in seq]
    eager, eager_conv, ours = [], [], []
    with torch.no_grad():  # as export/eager_compare.py (an online model takes gradients)
        for i in range(frames + 1):
            t0 = time.perf_counter()
            loop(tensors[i % len(seq)])[0].numpy()
            eager.append((time.perf_counter() - t0) * 1e3)
            eager_conv.append(timer.take())
            time.sleep(PAUSE_S)
            t0 = time.perf_counter()
            den.process(seq[i % len(seq)])
            ours.append((time.perf_counter() - t0) * 1e3)
            time.sleep(PAUSE_S)
    conv_nodes = node_ms_per_run(
        den._session.end_profiling(), lambda _node, op: "conv" if op in CONV_NODES else None
    )
    ours_conv = [run.get("conv", 0.0) for run in conv_nodes]

    def med(values: list[float]) -> float:
        return statistics.median(values[1:])  # after the warm-up frame

    return {
        "eager": med(eager),
        "eager_conv": med(eager_conv),
        "ort": med(ours),
        "ort_conv": med(ours_conv),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", action="append", help="demo:<family> or a .pt (repeatable)")
    ap.add_argument("--size", action="append", help="WIDTHxHEIGHT (repeatable)")
    ap.add_argument("--frames", type=int, default=7, help="timed frames per model and size")
    args = ap.parse_args(argv)
    tune_allocator()
    print(f"# {time.strftime('%Y-%m-%d %H:%M')} UTC; {' '.join(sys.argv)}")
    print(
        "| model | size | eager ms | eager convs ms | ORT ms | ORT convs ms | "
        "eager / ORT | eager / ORT convs |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for spec in args.model or ["demo:wskp"]:
        for size in args.size or ["1280x720"]:
            w, h = (int(v) for v in size.split("x"))
            r = measure(spec, h, w, args.frames)
            print(
                f"| {spec} | {size} | {r['eager']:.1f} | {r['eager_conv']:.1f} | {r['ort']:.1f} "
                f"| {r['ort_conv']:.1f} | {r['eager'] / r['ort']:.2f}x "
                f"| {r['eager'] / r['ort_conv']:.2f}x |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
