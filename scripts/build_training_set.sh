#!/usr/bin/env bash
# Build the v2 data sets of issue 31 (docs/data.md): a validation set and a training set.
# Resumable: run it again and it continues (complete sequences are skipped, a half-written one
# is finished from its partial.json). Every phase logs to <set>/render.log.
#
#   nohup setsid scripts/build_training_set.sh > /work/data/train_v2/build.log 2>&1 &
#
# PYTHON may be a separate, non-editable install (pip install --no-deps .), so that edits to
# the source tree do not change a render that is running or resumed later (docs/data.md).
#
# Settings (environment): DATA (/work/data), PYTHON (python), VARIANT (llvm_ad_rgb; falls back
# to scalar_rgb without LLVM 19), THREADS (1), TRAIN_N (1000 clips; raise it to grow the set:
# the first TRAIN_N clips stay the same), SHARD (e.g. 0/2 to run one of two processes at
# once on the training phase; empty: all), VALIDATION (1; 0 leaves out the validation phase:
# the set is committed as validation/, so a machine that lost /work/data needs only the
# training clips); for a quick trial SIZE (128x128), TRAIN_SPP (256),
# VAL_SPP (4096), VAL_HALF (4), FIRST_N (64).
#
# Training: 128x128, 8 frames, 1 spp input (+ an independent 1-spp colorB), 256-spp
# references, every kind but the held-out ones, base seed 10000.
# Validation: 128x128, 12 frames, 4096-spp references, base seed 20000: indices 0-3 the
# held-out kinds (corridor: an interior style; water: a material class), 4-7 the others.
set -euo pipefail
DATA=${DATA:-/work/data}
PYTHON=${PYTHON:-python}
VARIANT=${VARIANT:-llvm_ad_rgb}
THREADS=${THREADS:-1}
TRAIN_N=${TRAIN_N:-1000}
FIRST_N=${FIRST_N:-64}  # training clips rendered before the validation set
SHARD=${SHARD:-}
SIZE=${SIZE:-128x128}
TRAIN_SPP=${TRAIN_SPP:-256}
VAL_SPP=${VAL_SPP:-4096}
VAL_HALF=${VAL_HALF:-4}  # validation sequences of the held-out kinds, and as many of the others
VALIDATION=${VALIDATION:-1}
HELD_OUT=corridor,water
TRAIN_SEED=10000
VAL_SEED=20000
TRAIN=(--seed "$TRAIN_SEED" --frames 8 --size "$SIZE" --spp-ref "$TRAIN_SPP"
    --exclude-kinds "$HELD_OUT")
VAL=(--seed "$VAL_SEED" --frames 12 --size "$SIZE" --spp-ref "$VAL_SPP")
mkdir -p "$DATA/train_v2"
# `nice` alone does not yield under `setsid`: with the kernel's autogroup scheduling (on by
# default) a new session is a group of its own with a fair share against the shell's, so two
# niced renders took two thirds of the 2 cores from a benchmark. Lower the group's weight too.
if [ -w /proc/self/autogroup ]; then echo 19 > /proc/self/autogroup 2>/dev/null || true; fi
cd "$DATA"  # not a source tree: `python -m` puts the working folder first on sys.path

# The two sets must not share a scene seed (sequence i of a job has scene seed
# derive_seed(base, i)).
"$PYTHON" - "$TRAIN_SEED" "$VAL_SEED" "$TRAIN_N" <<'EOF'
import sys
from rtdenoise.datagen.seeds import derive_seed
train_seed, val_seed, n = (int(a) for a in sys.argv[1:])
common = {derive_seed(train_seed, i) for i in range(n)} & {derive_seed(val_seed, i) for i in range(64)}
if common:
    sys.exit(f"training and validation share scene seeds {sorted(common)}")
EOF

render() {  # render OUT ARGS...: one denoise-render run, appended to OUT/render.log
    local out=$1
    shift
    echo "=== $(date -u +%FT%TZ) denoise-render $out $*" >> "$out/render.log"
    nice -n 19 "$PYTHON" -m rtdenoise.cli.render "$out" "$@" --variant "$VARIANT" \
        --threads "$THREADS" >> "$out/render.log" 2>&1
}
shard=()
if [ -n "$SHARD" ]; then shard=(--shard "$SHARD"); fi

# 1. a first slice of the training set, so that training can start
render "$DATA/train_v2" "${TRAIN[@]}" -n "$FIRST_N" "${shard[@]}"
# 2. the validation set (small: 10-30 minutes a sequence on one core)
if [ "$VALIDATION" != 0 ] && { [ -z "$SHARD" ] || [ "${SHARD%%/*}" = 0 ]; }; then
    mkdir -p "$DATA/val_v2"
    render "$DATA/val_v2" "${VAL[@]}" -n "$VAL_HALF" --start-index 0 --kinds "$HELD_OUT"
    render "$DATA/val_v2" "${VAL[@]}" -n "$VAL_HALF" --start-index "$VAL_HALF" \
        --exclude-kinds "$HELD_OUT"
fi
# 3. the rest of the training set
render "$DATA/train_v2" "${TRAIN[@]}" -n "$TRAIN_N" "${shard[@]}"
echo "=== $(date -u +%FT%TZ) done" >> "$DATA/train_v2/render.log"
