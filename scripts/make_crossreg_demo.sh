#!/usr/bin/env bash
# Make demo:crossreg (Choi24): the seeded random initialisation, exported with its online-learning
# graph. No training data: the model learns while it runs. About 5 minutes on 2 cores (export).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=rtdenoise/assets/models
python -c "
from rtdenoise.models.checkpoint import save_checkpoint
from rtdenoise.models.registry import build_model
save_checkpoint('$OUT/crossreg.pt', build_model('crossreg'), {
    'note': 'Choi24 online denoiser at its seeded random initialisation (config seed 0); '
            'it learns while it runs (one Adam step per frame inside the ONNX graph)',
    'commands': ['scripts/make_crossreg_demo.sh'],
})
"
denoise-export "$OUT/crossreg.pt" -o "$OUT/crossreg.onnx" --overwrite
