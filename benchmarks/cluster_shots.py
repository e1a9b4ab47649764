"""Wall time of `denoise-run` over many shots: one after another vs one Ray task per shot.

Makes `--shots` shots from the committed test sequences (shot k = seq_(k mod 3), every
buffer and reference nearest-upscaled to `--size`, motion scaled with it, frames cycled to
`--frames`), then times, in this one invocation, each as its own `denoise-run` process:

- `sequential`: the shots one after another in one process (ONNX Runtime's default threads);
- `sequential --threads 1`: the same with one thread;
- `--cluster` (new local Ray): starts a local Ray on all cores, one task per shot, 1 thread each;
- `--cluster-address auto`: joins a Ray head the script started beforehand on port 6390
  (`ray start --head --block`, stopped after), so without the start-up a running cluster
  does not pay; one task per shot, 1 thread each.

Wall time includes the process start and model loads, as a user sees it; the Ray rows also
say how many Ray workers (CPUs) ran tasks. The outputs of `--threads 1` and of both Ray runs
must be byte-identical (checked).

    python benchmarks/cluster_shots.py                       # 8 shots, 16 frames 256x256

Needs the cluster extra (ray) and the `ray` command of the same environment.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from rtdenoise.runtime.sequences.exr import read_exr, write_exr
from rtdenoise.shipped import sample_sequences

BIN = Path(sys.executable).parent
PORT = 6390  # the benchmark's own Ray head (not Ray's default 6379)


def make_shots(root: Path, shots: int, frames: int, size: tuple[int, int]) -> list[Path]:
    """`shots` folders of `frames` canonical frames (and references) at `size` (H, W)."""
    sources = sample_sequences()
    folders = []
    for k in range(shots):
        src = sources[k % len(sources)]
        n = len(list(src.glob("frame_*.exr")))
        dst = root / f"shot_{k:02d}"
        dst.mkdir(parents=True)
        for t in range(frames):
            for kind in ("frame", "ref"):
                ch = read_exr(src / f"{kind}_{t % n:04d}.exr")
                h, w = next(iter(ch.values())).shape
                fy, fx = size[0] // h, size[1] // w
                up = {}
                for name, a in ch.items():
                    a = np.repeat(np.repeat(a, fy, 0), fx, 1)
                    if name == "motion.X":
                        a = a * fx
                    elif name == "motion.Y":
                        a = a * fy
                    up[name] = a.astype(np.float32)
                write_exr(dst / f"{kind}_{t:04d}.exr", up, half=True)
        folders.append(dst)
    return folders


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(argv)} failed ({proc.returncode}):\n{proc.stderr}")
    return wall


def start_head(cpus: int) -> subprocess.Popen:
    """A Ray head on this machine (`ray start --head --block`), once it answers."""
    argv = [str(BIN / "ray"), "start", "--head", "--block", f"--port={PORT}"]
    argv += [f"--num-cpus={cpus}", "--include-dashboard=false"]
    head = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    probe = "import ray; ray.init(address='auto', log_to_driver=False); ray.shutdown()"
    while time.monotonic() < deadline:
        if subprocess.run([sys.executable, "-c", probe], capture_output=True).returncode == 0:
            return head
        time.sleep(1)
    head.terminate()
    sys.exit("the Ray head did not start within 120 s")


def outputs(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*.exr")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shots", type=int, default=8)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--size", default="256x256", help="WIDTHxHEIGHT, multiples of 64")
    parser.add_argument("--model", default="demo:afn")
    parser.add_argument("--rounds", type=int, default=1, help="runs of each, in turn")
    args = parser.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    cpus = os.cpu_count() or 1
    names = [
        ("sequential", "1 process"),
        ("sequential --threads 1", "1 process"),
        ("--cluster (starts a local Ray)", f"{cpus} Ray workers"),
        ("--cluster-address auto (a running Ray)", f"{cpus} Ray workers"),
    ]
    walls: list[list[float]] = [[] for _ in names]
    same = True
    with tempfile.TemporaryDirectory(prefix="cluster-shots-") as tmp:
        root = Path(tmp)
        shots = [str(p) for p in make_shots(root / "in", args.shots, args.frames, (h, w))]
        run = [str(BIN / "denoise-run"), *shots, "--model", args.model]
        cluster = [*run, "--threads", "1", "--cluster"]
        for r in range(args.rounds):  # the four runs in turn, so that load drifts hit all
            out = [root / f"{k}_{r}" for k in ("seq", "seq1", "ray_new", "ray_auto")]
            walls[0].append(timed([*run, "-o", str(out[0])]))
            walls[1].append(timed([*run, "-o", str(out[1]), "--threads", "1"]))
            walls[2].append(timed([*cluster, "-o", str(out[2])]))
            head = start_head(cpus)
            try:
                walls[3].append(timed([*cluster, "--cluster-address", "auto", "-o", str(out[3])]))
            finally:
                head.terminate()  # `ray start --block` stops the Ray processes it started
                head.wait(timeout=60)
            n_out = len(outputs(out[1]))
            same = same and outputs(out[1]) == outputs(out[2]) == outputs(out[3])
            for folder in out:
                shutil.rmtree(folder)
    rows = [(*name, statistics.median(t), t) for name, t in zip(names, walls, strict=True)]
    base = rows[0][2]
    print(
        f"{datetime.date.today()}, {platform.machine()} {cpus} cores, Python "
        f"{platform.python_version()}: {args.shots} shots x {args.frames} frames "
        f"{w}x{h}, {args.model}; {n_out} outputs, {args.rounds} round(s)"
    )
    print()
    print("| run | workers | wall s (median) | each round s | sequential / this |")
    print("|---|---|---:|---|---:|")
    for name, workers, wall, each in rows:
        rounds = ", ".join(f"{t:.1f}" for t in each)
        print(f"| {name} | {workers} | {wall:.1f} | {rounds} | {base / wall:.2f}x |")
    print()
    print(f"outputs of --threads 1 and both Ray runs byte-identical: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
