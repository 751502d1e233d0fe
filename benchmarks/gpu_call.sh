#!/usr/bin/env bash
# One device call's worth of GPU measurements, most important first, within BUDGET_S seconds
# (a device call lasts at most 10 minutes; BENCHMARKS.md records what each stage gave).
#
#   here:  make bench-gpu-pack; cp -r <the walk's 100 px lego> data/lego100
#          (and the wheels of tyro and pydantic in .whl/, which the GPU image lacks)
#   there: bash benchmarks/gpu_call.sh        (device tool: carry data/gpu data/lego100 .whl)
#
# Stages: (1) the fused hash kernels against the PyTorch path at the paper grid's size;
# (2) the paper preset's step time with each kernel (short uniform trials at 400 px);
# (3) one paper-scale trial (400 px, 10k steps, 200 test views) of the paper preset; (4) at
#     100 px, the walk's start, its last two steps (the paper preset with "last_sample", then with
#     its fixed background) and nerfacto's own last_sample, several runs at once, in the time left.
# Everything lands in $OUT/gpu.tgz, re-packed after each stage, so a call cut short still
# brings back what finished.
set -u
OUT=${OUT:-results/gpu-call}
BUDGET_S=${BUDGET_S:-540}
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

echo "== (1) kernel, $(left) s left"
timeout 90 python3 benchmarks/bench_gpu.py kernel --device cuda --json "$RES/kernel.json"
pack

for kernel in torch triton; do
    echo "== (2) step time, $kernel kernels, $(left) s left"
    timeout 120 python3 benchmarks/bench_gpu.py trial --data data/gpu/lego.npz --device cuda --method uniform \
        --steps 500 --test-views 3 --save-renders 0 --hash-kernel "$kernel" \
        --out "/tmp/trial-$kernel" --json "$RES/step-$kernel.json" | tail -12
    pack
done

echo "== (3) paper-scale trial, $(left) s left"
timeout $(($(left) - 170)) python3 benchmarks/bench_gpu.py trial --data data/gpu/lego.npz --device cuda \
    --engine paper --save-renders 3 --out /tmp/trial-full --json "$RES/trial-paper.json" | tail -12
find /tmp/trial-full -name "*_render_vs_gt.png" | head -3 | xargs -r cp -t "$RES/"
pack

echo "== (4) walk at 100 px, $(left) s left"
for entry in start rays-per-step background paper-last-composited-bg; do
    timeout $(($(left) - 15)) python3 benchmarks/bench_engine_walk.py --data data/lego100 --out "$RES/walk-$entry" \
        --entries "$entry" --seeds 0 1 --device cuda > "$RES/walk-$entry.log" 2>&1 &
done
wait
pack
ls -R "$RES" | head -60
