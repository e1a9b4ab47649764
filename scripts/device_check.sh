#!/usr/bin/env bash
# The PyTorch-on-GPU checks of rtdenoise as one prepared run on a lent GPU machine (Python 3.12
# with torch, numba, onnx, onnxscript, onnxruntime (CPU), typer, rich, pytest, matplotlib; no
# network there). ONNX Runtime's CUDA package is too large to carry, so the GPU side checked is
# PyTorch's: tests/test_gpu.py, denoise-train --device cuda, denoise-bench compare --device cuda.
#
#   scripts/device_check.sh prepare    # here: the missing packages as cp312 files in .device/
#   scripts/device_check.sh run        # there, in one call carrying .device/, e.g. with the
#                                      # workplace's device tool: command "scripts/device_check.sh
#                                      # run", carry [".device"], timeout 540 s
#
# `run` writes its logs, a CUDA-trained checkpoint and the compare JSON under $OUT (a temp folder
# when unset). `DEVICE=cpu INSTALL=0 STEPS=5 SIZES=64x64 scripts/device_check.sh run` runs the
# same steps in this machine's environment (a check of the script, not of a GPU).
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-cuda}
STEPS=${STEPS:-300}               # training steps
SIZES=${SIZES:-1280x720 1920x1080} # compare's frame sizes
CARRY=.device
WHEEL_ARGS=(--no-deps --only-binary=:all: --python-version 3.12 --implementation cp
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64
    --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)

prepare() {
    grep -qx "/$CARRY/" .git/info/exclude 2>/dev/null || echo "/$CARRY/" >>.git/info/exclude
    rm -rf "$CARRY" && mkdir -p "$CARRY"
    local openexr
    openexr=$(python3 -c "import importlib.metadata as m; print(m.version('OpenEXR'))")
    python3 -m pip download -q "${WHEEL_ARGS[@]}" -d "$CARRY" "OpenEXR==$openexr" \
        "onnxruntime-extensions==0.15.2" "cffi==1.17.1" "pyoidn==2.5.1"
    # pyoidn's wheel (88 MB) holds OIDN's SYCL and HIP devices besides CUDA's and the CPU's;
    # its CUDA and CPU devices alone travel, packed (the device tool carries 64 MiB at most).
    local tmp
    tmp=$(mktemp -d)
    python3 -m zipfile -e "$CARRY"/pyoidn-*.whl "$tmp"
    rm -f "$CARRY"/pyoidn-*.whl
    rm -rf "$tmp/pyoidn/oidn/lib/cmake"
    (cd "$tmp/pyoidn/oidn/lib" && rm -f libur_* libsycl* libumf* libtbbbind* libtbb.so \
        libtbb.so.12.19 libOpenImageDenoise_device_hip* libOpenImageDenoise_device_sycl* \
        libOpenImageDenoise.so.2* && ln -s libOpenImageDenoise.so libOpenImageDenoise.so.2)
    tar -czf "$CARRY/pyoidn-cuda-cpu.tar.gz" -C "$tmp" pyoidn pyoidn-2.5.1.0.dist-info
    rm -rf "$tmp"
    du -sh "$CARRY"
}

run() {
    OUT=${OUT:-$(mktemp -d)}
    if [ "${INSTALL:-1}" = 1 ]; then
        local site=/tmp/rtdenoise-site
        python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$site" \
            "$CARRY"/*.whl
        tar -xzf "$CARRY/pyoidn-cuda-cpu.tar.gz" -C "$site"
        python3 -m pip install -q --no-deps --no-build-isolation --target "$site" .
        export PYTHONPATH="$site${PYTHONPATH:+:$PYTHONPATH}" PATH="$site/bin:$PATH"
    fi
    export PYTHONUNBUFFERED=1
    (nvidia-smi -L || true) | tee "$OUT/machine.txt"
    python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())" \
        | tee -a "$OUT/machine.txt"
    local rc=0
    RTDENOISE_TEST_DEVICE=$DEVICE python3 -m pytest -q -p no:cacheprovider tests/test_gpu.py \
        tests/test_device.py 2>&1 | tee "$OUT/pytest.log" || rc=1
    denoise-train rtdenoise/assets/sequences/seq_000 rtdenoise/assets/sequences/seq_001 \
        --val rtdenoise/assets/sequences/seq_002 -o "$OUT/wskp_$DEVICE.pt" --family wskp \
        --device "$DEVICE" --steps "$STEPS" --crop 64 --frames 6 --batch 8 \
        2>&1 | tail -n 40 | tee "$OUT/train.log" || rc=1
    local size_args=()
    for size in $SIZES; do size_args+=(--size "$size"); done
    denoise-bench compare demo:afn demo:wskp demo:nbg --eager --device "$DEVICE" \
        "${size_args[@]}" --repeats 5 --json "$OUT/compare_$DEVICE.json" \
        2>&1 | tee "$OUT/compare.log" || rc=1
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
