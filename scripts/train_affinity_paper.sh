#!/usr/bin/env bash
# Isik21's affinity denoiser at the paper's size (the family defaults, 941,408 parameters) on
# the v2 training set (docs/data.md), in two stages (benchmarks/README.md, "Isik21 at the
# paper's size on per-sample clips"):
#
#   1. the pixel-mean clips of $DATA/train_v2 (S = 1), a schedule of STEPS1 steps run up to
#      STOP1 (default: all of it; fewer leave the rate higher for stage 2), in pieces of PIECE steps:
#      each piece resumes the last (--resume) and reads the set again, so that clips a render
#      finished meanwhile join the run;
#   2. the same clips rendered again with two per-sample layers ($DATA/train_v2_s2, made here
#      with --references-from, which copies the references), S drawn from 1, 2 per batch,
#      STEPS2 steps from stage 1's weights with the edge margin MARGIN (the frame's edge pixels
#      repeated on every side, `edge_margin`), which keeps a light at the frame's edge in place.
#
# Resumable: run it again and it goes on from the last checkpoint of the stage it was in.
#
#   OUT=/work/exp/aff DATA=/work/data scripts/train_affinity_paper.sh
#
# Settings (environment): DATA (/work/data), OUT (./affinity_paper), STEPS1 (3000), STOP1
# (STEPS1), PIECE (1000), STEPS2 (1000), MARGIN (8), THREADS (1), RENDER (denoise-render: the S = 2 render;
# the references' variant, llvm_ad_rgb, needs libLLVM 19, docs/data.md "Variants").
set -euo pipefail
DATA=${DATA:-/work/data}
OUT=${OUT:-./affinity_paper}
STEPS1=${STEPS1:-3000}
STOP1=${STOP1:-$STEPS1}
PIECE=${PIECE:-1000}
STEPS2=${STEPS2:-1000}
MARGIN=${MARGIN:-8}
THREADS=${THREADS:-1}
RENDER=${RENDER:-denoise-render}
mkdir -p "$OUT" "$DATA/cache"
COMMON=(--family affinity --oversample lights=3 --crop 64 --frames 6 --batch 2 --schedule cosine
    --warmup 0.05 --threads "$THREADS" --rel-l1-weight 0.05 --cache "$DATA/cache")

step_of() {  # the step a checkpoint reached (0 if there is none)
    [ -f "$1" ] || { echo 0; return; }
    python - "$1" <<'EOF'
import sys
import torch
print(int(torch.load(sys.argv[1], weights_only=True)["meta"].get("step", 0)))
EOF
}

# 1. pixel-mean clips, in pieces
S1="$OUT/stage1.pt"
while [ "$(step_of "$S1")" -lt "$STOP1" ]; do
    done_steps=$(step_of "$S1")
    stop=$(( done_steps + PIECE < STOP1 ? done_steps + PIECE : STOP1 ))
    resume=()
    if [ -f "$S1" ]; then resume=(--resume "$S1"); fi
    denoise-train "$DATA/train_v2" "${COMMON[@]}" --config '{"padding": "replicate"}' \
        --steps "$STEPS1" --stop-at "$stop" --lr 5e-4 --seed 0 --save-every 100 \
        --dark-edge-weight 0.25 "${resume[@]}" -o "$S1"
done

# 2. the complete clips again with two per-sample layers (references copied), then stage 2
"$RENDER" "$DATA/train_v2_s2" --seed 10000 --frames 8 --size 128x128 --spp-ref 256 \
    --exclude-kinds corridor,water -n 1000 --variant llvm_ad_rgb --threads 1 \
    --samples 2 --references-from "$DATA/train_v2"
S2="$OUT/stage2.pt"
if [ "$(step_of "$S2")" -lt "$STEPS2" ]; then
    if [ -f "$S2" ]; then start=(--resume "$S2"); else start=(--init-from "$S1"); fi
    denoise-train "$DATA/train_v2_s2" "${COMMON[@]}" \
        --config "{\"padding\": \"replicate\", \"edge_margin\": $MARGIN}" --samples 1,2 \
        --steps "$STEPS2" --lr 2.5e-4 --seed 1 --save-every 100 --dark-edge-weight 1 \
        "${start[@]}" -o "$S2"
fi
echo "done: $S2"
