"""Average the weights of checkpoints of one model (rtdenoise.models.weight_average):

    python scripts/average_checkpoints.py STAGE2.pt STAGE3.pt --weights 0.7 0.3 -o SOUP.pt

The output is a checkpoint like any other (`denoise-export SOUP.pt -o soup.onnx`); its meta lists
every source's training commands, then this one.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from rtdenoise.models.checkpoint import save_checkpoint
from rtdenoise.models.weight_average import average_checkpoints


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--weights", nargs="+", type=float, required=True, help="one each, sum 1")
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args(argv)
    if args.output.exists():
        ap.error(f"{args.output} exists; not overwritten")
    command = shlex.join(["python", "scripts/average_checkpoints.py", *(argv or sys.argv[1:])])
    model, meta = average_checkpoints(args.checkpoints, args.weights, command)
    save_checkpoint(args.output, model, meta)
    print(f"wrote {args.output}: {model.family}, weights {args.weights}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
