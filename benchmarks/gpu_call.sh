#!/usr/bin/env bash
# One device call's worth of GPU measurements, most important first, within BUDGET_S seconds
# (a device call lasts at most 10 minutes; BENCHMARKS.md records what each stage gave).
#
#   here:  make bench-gpu-pack (data/gpu/lego.npz); the 400 px mic pack (data/gpu/mic.npz:
#          `nerfaug scene prepare <NeRF-synthetic mic> --out data/mic400 --width 400`, then
#          `python benchmarks/bench_gpu.py pack --from data/mic400 --out data/gpu/mic.npz`);
#          the walk's 100 px lego in data/lego100; the wheels of tyro and pydantic in .whl/
#          (the GPU image lacks them)
#   there: bash benchmarks/gpu_call.sh        (device tool: carry data/gpu data/lego100 .whl)
#
# Stages: (1) the dense-view check of the paper preset (all training views, 100 px, 1000 steps;
#     the CPU gave 22.45 dB, so this checks the GPU path, Triton kernels included, against it);
# (2) which part of a step float16 autocast changes, and float16 trainings with a GradScaler, with
#     and without the proposal networks in float32 (bench_precision.py); (3) one paper-scale
#     trial (400 px, 10k steps, 200 test views) of the paper preset as it now is (fixed
#     background, float32) on lego; (4) the same on mic, in the time left.
# Everything lands in $OUT/gpu.tgz, re-packed after each stage, so a call cut short still
# brings back what finished.
set -u
OUT=${OUT:-results/gpu-call}
BUDGET_S=${BUDGET_S:-560}
RES=/tmp/gpu-results
mkdir -p "$OUT" "$RES"
export PYTHONUNBUFFERED=1
pack() { tar czf "$OUT/gpu.tgz" -C "$RES" .; }
left() { echo $((BUDGET_S - SECONDS)); }

if [ -d .whl ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        && export PYTHONPATH=/tmp/site
fi
nvidia-smi -L | tee "$RES/device.txt"
python3 -c "import torch, triton; print(torch.__version__, triton.__version__)" | tee -a "$RES/device.txt"

echo "== (1) dense-view check of paper, $(left) s left"
timeout 100 python3 benchmarks/bench_dense.py --data data/lego100 --presets paper --device cuda \
    --out "$RES/dense-paper.json" | tail -4
pack

echo "== (2) half precision, $(left) s left"
timeout 200 python3 benchmarks/bench_precision.py --data data/lego100 --engine paper --device cuda \
    --at-steps 100 1000 --train-half 1000 --train-keep proposal --json "$RES/precision.json" | tail -16
pack

for scene in lego mic; do
    budget=$(($(left) - 10))
    if [ "$budget" -lt 200 ]; then echo "== (3/4) $scene skipped: $budget s left"; continue; fi
    echo "== (3/4) paper-scale trial on $scene, $budget s left"
    timeout "$budget" python3 benchmarks/bench_gpu.py trial --data "data/gpu/$scene.npz" --device cuda \
        --engine paper --save-renders 3 --out "/tmp/trial-$scene" --json "$RES/trial-paper-$scene.json" | tail -12
    mkdir -p "$RES/$scene" && find "/tmp/trial-$scene" -name "*_render_vs_gt.png" | head -3 | xargs -r cp -t "$RES/$scene/"
    pack
done
ls -R "$RES" | head -60
