#!/usr/bin/env bash
# The GPU study's device call (docs/study-plan.md, "Plan of 2026-11-27" and its amendment of
# 2026-11-28): the call measures its machine first (a few training steps of the study's engine at
# the study's size, alone and in a trial batch, and one test view), then runs the plan's next runs
# that the committed table lacks, in the plan's order (ours against uniform on the first scene
# first), as many at a time as the GPU's memory holds and as fit the time left, for BUDGET_S
# seconds in all (a device call lasts at most 10 minutes). Every finished run comes back in
# $OUT/gpu-study.tar.gz, re-written after each batch, with gpu-call.json: what was measured, each
# batch's predicted and actual time, and why the call stopped. Merge it here with
# `python benchmarks/gpu_study.py merge gpu-study.tar.gz`.
#
#   here:  make gpu-study-ready (the packs under data/gpu-study/, at most 60 MiB a call: set
#          SCENES or move packs aside to carry fewer; the wheels the GPU image lacks in .whl/)
#   there: bash benchmarks/gpu_study.sh (device tool: carry data/gpu-study and .whl)
#
# DEVICE=cpu is the same call on a CPU at toy size, from a fresh clone with no download: a toy
# scene made by the script itself and a small engine that trains in trial batches (what CI runs:
# `DEVICE=cpu BUDGET_S=120 OUT=dir bash benchmarks/gpu_study.sh`).
# PART=smoke measures the machine and runs nothing. PYTHON: the interpreter (default python3).
set -u
OUT=${OUT:-results/gpu-study-call}
BUDGET_S=${BUDGET_S:-560}
DEVICE=${DEVICE:-cuda}
PART=${PART:-all}
PYTHON=${PYTHON:-python3}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
left() { echo $((BUDGET_S - SECONDS)); }
cd "$(dirname "$0")/.."

WORK=$(mktemp -d /tmp/gpu-study.XXXXXX)
if [ "$DEVICE" = cpu ]; then
    # The toy scene (3 initial, 12 candidate, 4 test views of 24 px) and an engine with the paper
    # engine's structure (hash grid, proposal sampler) that trains in trial batches, small.
    ARGS=(--device cpu --toy "$WORK/toy/sphere" --packs "$WORK/packs" --table "$WORK/no-table.json"
          --engine "nerfacto-cpu+sampler.num_samples=8+sampler.proposal.samples=16,8+optimiser.batch_size=64" --preset tiny
          --resolution 24 --steps 30 --threads 1 --margin-s 5 --probe-steps 8)
    KEEP=10
else
    . benchmarks/gpu_env.sh "$OUT/device.txt"
    ARGS=(--device "$DEVICE")
    KEEP=40
fi
[ "$PART" = smoke ] && ARGS+=(--measure-only)

# The script's budget covers the interpreter's start (not on its own clock): KEEP seconds of it
# are kept back, and the timeout is a safety net past the budget, not the plan.
BUDGET=$(( $(left) - KEEP > 1 ? $(left) - KEEP : 1 ))
echo "== study on $DEVICE: the next runs of the plan, $BUDGET s for them ($(left) s left)"
timeout $(( BUDGET + KEEP + 20 )) "$PYTHON" benchmarks/gpu_study.py run --work "$WORK/work" --budget-s "$BUDGET" \
    --archive "$OUT/gpu-study.tar.gz" --quiet "${ARGS[@]}" > "$OUT/study.log" 2>&1
STATUS=$?
echo "study exit $STATUS"; tail -20 "$OUT/study.log"
if [ ! -f "$OUT/gpu-study.tar.gz" ]; then
    # Nothing came back from the study itself: say why beside where the archive would be.
    { echo "no archive: the study exited with $STATUS after $SECONDS s of BUDGET_S=$BUDGET_S"
      [ "$STATUS" = 124 ] && echo "(stopped by its timeout)"
      echo "--- the end of its log:"; tail -20 "$OUT/study.log"; } > "$OUT/no-runs.txt"
    cat "$OUT/no-runs.txt"
fi
rm -rf "$WORK"
ls -la "$OUT"
