#!/usr/bin/env bash
# Render a training set with Mitsuba's CUDA variant, train the larger light models on it and
# bring the checkpoints back: issue 31's data engine and training recipe on a lent GPU machine
# (Python 3.12 with torch, numba, onnx, onnxscript, onnxruntime, typer, rich; no network, no
# mitsuba, drjit or OpenEXR there), in one call of at most 10 minutes.
#
#   scripts/gpu_quality.sh prepare   # here: OpenEXR, drjit and a repacked mitsuba as cp312 files
#                                    # in .device_quality/ (scripts/pack_mitsuba.py: 24 MiB)
#   scripts/gpu_quality.sh run       # there, in one call carrying .device_quality/, e.g. with
#                                    # the workplace's device tool: command
#                                    # "scripts/gpu_quality.sh run", carry [".device_quality"],
#                                    # timeout 590 s
#
# `run` renders for RENDER_S seconds (RENDER_PROCS processes, one --shard each, base seed 10000,
# the held-out kinds excluded: the same clips as scripts/build_training_set.sh, so a render here
# and there make one set), then trains each of CANDIDATES (afn also with Lee24's fusion network)
# at its family's OIDN-fast-budget size
# (benchmarks/capacity_budget.py) with the OIDN-like recipe for STEPS steps, all at once on the
# one GPU, validating on the committed validation set. $OUT gets the checkpoints (their meta
# holds the training command), render.json (clips, seconds, clips per minute, the render command)
# and logs.tar.gz. Here, afterwards: denoise-export each and
# `denoise-bench compare` them on validation/ beside OIDN (benchmarks/README.md).
#
# `DEVICE=cpu VARIANT=llvm_ad_rgb INSTALL=0 RENDER_S=60 STEPS=4 SIZE=32x32 CANDIDATES=nbg scripts/gpu_quality.sh run`
# runs the same steps in this machine's environment: a check of the script, not of a GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-cuda}
VARIANT=${VARIANT:-cuda_ad_rgb}
RENDER_S=${RENDER_S:-210}       # seconds of rendering
RENDER_PROCS=${RENDER_PROCS:-8} # render processes sharing the GPU (one --shard each)
STEPS=${STEPS:-3000}            # training steps per family
TRAIN_S=${TRAIN_S:-300}         # a training run still going then is stopped (its last save kept)
SIZE=${SIZE:-128x128}
CANDIDATES=${CANDIDATES:-afn afn_fusion nbg wskp} # a candidate is FAMILY or FAMILY_VARIANT
DATA=${DATA:-/tmp/rtdenoise-train}
CARRY=.device_quality
WHEEL_ARGS=(--no-deps --only-binary=:all: --python-version 3.12 --implementation cp
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)

config_of() { # a candidate's config: its family's OIDN-fast-budget size (benchmarks/README.md)
    case "$1" in
    afn) echo '{"widths": [32, 24, 32, 48, 64]}' ;;
    afn_fusion) echo '{"widths": [32, 24, 32, 48, 64], "fusion": "network"}' ;; # Lee24 Fig. 2c
    nbg) echo '{"hidden": 64}' ;;
    wskp) echo '{"width": 32, "layers": 3}' ;;
    *) echo '{}' ;;
    esac
}

prepare() {
    grep -qx "/$CARRY/" .git/info/exclude 2>/dev/null || echo "/$CARRY/" >>.git/info/exclude
    rm -rf "$CARRY" && mkdir -p "$CARRY/raw"
    v() { python3 -c "import importlib.metadata as m; print(m.version('$1'))"; }
    python3 -m pip download -q "${WHEEL_ARGS[@]}" -d "$CARRY/raw" "OpenEXR==$(v OpenEXR)" \
        "drjit==$(v drjit)" "mitsuba==$(v mitsuba)"
    python3 scripts/pack_mitsuba.py "$CARRY"/raw/mitsuba-*.whl -o "$CARRY"
    mv "$CARRY"/raw/[Oo]pen[Ee][Xx][Rr]-*.whl "$CARRY"/raw/drjit-*.whl "$CARRY"/
    rm -rf "$CARRY/raw"
    du -sh "$CARRY"
    echo "the working tree travels too: $(git ls-files -z | du -bc --files0-from=- | tail -1 | cut -f1) bytes tracked"
}

render() { # RENDER_S seconds of training clips, RENDER_PROCS shards at once
    mkdir -p "$DATA"
    local start pids=() i
    start=$(date +%s)
    for ((i = 0; i < RENDER_PROCS; i++)); do
        local cmd=(denoise-render "$DATA" --seed 10000 --frames 8 --size "$SIZE" --spp-ref 256
            --exclude-kinds corridor,water -n 100000 --shard "$i/$RENDER_PROCS"
            --variant "$VARIANT" --threads 2)
        echo "${cmd[*]}" >"$LOGS/render_$i.cmd"
        timeout "$RENDER_S" "${cmd[@]}" >"$LOGS/render_$i.log" 2>&1 &
        pids+=($!)
    done
    for pid in "${pids[@]}"; do wait "$pid" || true; done # timeout's 124 is the plan
    python3 - "$DATA" "$(($(date +%s) - start))" "$OUT/render.json" "$VARIANT" \
        "$(head -n 1 "$LOGS/render_0.cmd")" <<'EOF'
import collections, json, sys
from pathlib import Path
data, seconds, out, variant, command = Path(sys.argv[1]), int(sys.argv[2]), *sys.argv[3:]
metas = [json.loads(p.read_text()) for p in sorted(data.glob("seq_*/meta.json"))]
report = {"clips": len(metas), "seconds": seconds, "variant_asked": variant, "command": command,
          "variants": dict(collections.Counter(m["renderer"]["variant"] for m in metas)),
          "kinds": dict(collections.Counter(m.get("kind", "?") for m in metas)),
          "clips_per_minute": round(60 * len(metas) / max(seconds, 1), 1)}
Path(out).write_text(json.dumps(report, indent=1))
print(json.dumps(report))
EOF
}

train() { # every candidate of CANDIDATES at once on the one device
    local seqs=() val=() pids=() name
    for d in "$DATA"/seq_*/; do [ -f "$d/meta.json" ] && seqs+=("$d"); done
    for d in validation/seq_*/; do [ -f "$d/meta.json" ] && val+=(--val "$d"); done
    if [ "${#seqs[@]}" -lt 2 ]; then
        echo "only ${#seqs[@]} complete clips in $DATA: nothing to train on" >&2
        return 1
    fi
    for name in $CANDIDATES; do
        timeout "$TRAIN_S" denoise-train "${seqs[@]}" "${val[@]}" -o "$OUT/$name.pt" \
            --family "${name%%_*}" --config "$(config_of "$name")" --device "$DEVICE" --steps "$STEPS" \
            --loss l1-ms-ssim --schedule onecycle --rotations --permute-channels \
            --exposure auto --crop "${SIZE%%x*}" --frames 8 --batch 16 --workers 4 \
            --cache "$DATA/cache_$name" --save-every 250 --log-every 100 --no-progress \
            >"$LOGS/train_$name.log" 2>&1 &
        pids+=($!)
    done
    local rc=0
    for pid in "${pids[@]}"; do wait "$pid" || rc=1; done
    return $rc
}

run() {
    OUT=${OUT:-$(mktemp -d)}
    LOGS=$(mktemp -d)
    if [ "${INSTALL:-1}" = 1 ]; then
        local site=/tmp/rtdenoise-site
        python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" \
            "$CARRY"/*.whl
        python3 -m pip install -q --no-deps --no-build-isolation --target "$site" .
        export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}" PATH="$site/bin:$PATH"
    fi
    export PYTHONUNBUFFERED=1
    (nvidia-smi -L 2>/dev/null || echo "no nvidia-smi") | tee "$LOGS/machine.txt"
    local rc=0
    render || rc=1
    train || rc=1
    tail -n 3 "$LOGS"/train_*.log || true
    tar -czf "$OUT/logs.tar.gz" -C "$LOGS" . # the device tool brings back 8 files at most
    echo "results in $OUT (exit $rc)"
    return $rc
}

case "${1:-}" in
prepare) prepare ;;
run) run ;;
*)
    echo "usage: $0 prepare|run" >&2
    exit 2
    ;;
esac
