#!/usr/bin/env bash
# Regenerate the committed test sequences (3 x 8 frames, 64x64, float16, 1024-spp references).
# Needs the data extra: pip install -e '.[data]'. About 3 minutes on 2 cores with scalar_rgb.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=rtdenoise/assets/sequences
python -m rtdenoise.cli.render "$OUT" --sequences 3 --frames 8 --size 64x64 \
    --spp-ref 1024 --seed 1 --variant scalar_rgb --kinds legacy --overwrite
python -c "
from rtdenoise.datagen.validate import warp_report
from rtdenoise.shipped import sample_sequences
for seq in sample_sequences():
    gains = [round(float(r.gain_db), 1) for r in warp_report(seq)]
    print(seq.name, 'warp gain dB per frame:', gains)
"
du -sh "$OUT"
