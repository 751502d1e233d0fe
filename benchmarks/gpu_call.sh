#!/usr/bin/env bash
# One device call's worth of GPU measurements, most important first, within BUDGET_S seconds
# (a device call lasts at most 10 minutes; BENCHMARKS.md records what each stage gave).
#
#   here:  make bench-gpu-pack (data/gpu/lego.npz); the 400 px mic pack (data/gpu/mic.npz:
#          `nerfaug scene prepare <NeRF-synthetic mic> --out data/mic400 --width 400`, then
#          `python benchmarks/bench_gpu.py pack --from data/mic400 --out data/gpu/mic.npz`);
#          the walk's 100 px lego in data/lego100; the wheels of tyro and pydantic in .whl/
#          (the GPU image lacks them)
#   there: PART=trials bash benchmarks/gpu_call.sh, then PART=checks (device tool: carry data/gpu data/lego100 .whl)
#
# Parts, one device call each (PART=trials, then PART=checks on the still-warm machine; PART=solo
# is one mic trial alone, PART=solo-checks that trial and then the checks in the time left):
# trials: one paper-scale trial (400 px, 10k steps, 200 test views) of the paper preset as it now
#   is (fixed background, float32) on lego and one on mic, both at once on the GPU (their times
#   are shared, their quality is not);
# checks: why fp16 autocast stalls the paper preset (on 2026-11-26 fp16 trained as float32 does
#   only with the field's colour network kept in float32; BENCHMARKS.md). On the CPU the colour
#   network's float16 gradient is mostly underflow at 4096 rays a step, yet training does not
#   stall there, so two GPU-only suspects are measured: the loss scale (from 2^23, the scale
#   tiny-cuda-nn's float16 modules work at: 2^16 times their own 128) and cuBLAS's float16
#   partial sums (--exact-fp16-sums); then the dense-view check of the paper preset in the time
#   left.
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

. "$(dirname "$0")/gpu_env.sh" "$RES/device.txt"

trial() {  # scene, seconds
    echo "== paper-scale trial on $1, $2 s allowed, $(left) s left"
    timeout "$2" python3 benchmarks/bench_gpu.py trial --data "data/gpu/$1.npz" --device cuda \
        --engine paper --save-renders 3 --out "/tmp/trial-$1" --json "$RES/trial-paper-$1.json" > "$RES/trial-$1.log" 2>&1
    tail -12 "$RES/trial-$1.log"
    mkdir -p "$RES/$1" && find "/tmp/trial-$1" -name "*_render_vs_gt.png" | head -3 | xargs -r cp -t "$RES/$1/"
    pack
}

PART=${PART:-trials}
if [ "$PART" = solo ] || [ "$PART" = solo-checks ]; then
    # One paper-scale trial with the GPU to itself: the clean time of a trial (the 2026-11-26
    # trials shared the GPU two at a time).
    trial mic 300
    [ "$PART" = solo ] || [ "$(left)" -lt 150 ] || PART=checks
fi
if [ "$PART" = trials ]; then
    trial lego $(($(left) - 20)) &
    sleep 5
    trial mic $(($(left) - 20))
    wait
    pack
elif [ "$PART" = checks ]; then
    precision() {  # name, then bench_precision.py's options beyond float32 and plain fp16
        timeout $(( $(left) < 200 ? $(left) - 60 : 200 )) python3 benchmarks/bench_precision.py --data data/lego100 \
            --engine paper --device cuda --at-steps 20 --train-half 1000 "${@:2}" --json "$RES/precision-$1.json" | tail -10
        pack
    }
    echo "== half precision: the loss scale from 2^23, $(left) s left"
    precision scale --train-scales 23
    echo "== half precision: float32 partial sums in float16 products, $(left) s left"
    precision exact-sums --exact-fp16-sums
    echo "== dense-view check of paper, $(left) s left"
    timeout 120 python3 benchmarks/bench_dense.py --data data/lego100 --presets paper --device cuda \
        --out "$RES/dense-paper.json" | tail -4
    pack
fi
ls -R "$RES" | head -60
