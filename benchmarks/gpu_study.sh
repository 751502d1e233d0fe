#!/usr/bin/env bash
# The GPU study's device call (docs/study-plan.md, "Plan of 2026-11-27"): a short smoke run of the
# trial batches on the GPU, then the next runs the committed table lacks, for what is left of
# BUDGET_S seconds (a device call lasts at most 10 minutes). What finished comes back in
# $OUT/gpu-study.tar.gz (re-written after each part, so a call cut short still brings back what
# finished); merge it here with `python benchmarks/gpu_study.py merge gpu-study.tar.gz`.
#
#   here:  make gpu-study-ready (the packs under data/gpu-study/, at most 60 MiB a call: set
#          SCENES or move packs aside to carry fewer; the wheels the GPU image lacks in .whl/)
#   there: bash benchmarks/gpu_study.sh (device tool: carry data/gpu-study and .whl)
#
# PART=smoke runs the smoke part alone; PART=study skips it.
set -u
OUT=${OUT:-results/gpu-study-call}
BUDGET_S=${BUDGET_S:-560}
PART=${PART:-all}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
left() { echo $((BUDGET_S - SECONDS)); }

. "$(dirname "$0")/gpu_env.sh" "$OUT/device.txt"

if [ "$PART" != study ]; then
    # The same code at toy size: two trials of two methods in one trial batch on the GPU (the
    # fused hash kernels with per-run tables), a minute at most.
    echo "== smoke: one trial batch at toy size, $(left) s left"
    timeout 120 python3 benchmarks/gpu_study.py run --work /tmp/gpu-smoke --table /tmp/no-table.json \
        --preset tiny --resolution 100 --steps 60 --trials 2 --methods uniform ours --budget-s 90 \
        --archive "$OUT/gpu-smoke.tar.gz" --quiet > "$OUT/smoke.log" 2>&1
    echo "smoke exit $?"; tail -5 "$OUT/smoke.log"
fi
if [ "$PART" != smoke ]; then
    echo "== study: the next runs of the plan, $(left) s left"
    timeout $(($(left) - 10)) python3 benchmarks/gpu_study.py run --budget-s $(($(left) - 40)) \
        --archive "$OUT/gpu-study.tar.gz" > "$OUT/study.log" 2>&1
    echo "study exit $?"; tail -20 "$OUT/study.log"
fi
ls -la "$OUT"
