#!/usr/bin/env bash
# One sitting of the real-scene study (docs/study-plan.md): every planned cell in the plan's order,
# each resumed where the table leaves it, so a sitting can stop anywhere and the next one goes on.
# Record the sitting in docs/study-plan.md before starting it.
#
#   FROZEN  a checkout of the study's frozen code (the runs' fingerprints must match the table's;
#           `git worktree add FROZEN <commit>`, the commit named in the last sitting's entry)
#   DATA    the prepared scenes: for each of mic, maryRose, dtu_scan24, moldGoldCape,
#           `nerfaug scene prepare DOWNLOADS/<scene> --out DATA/<scene> --width 100` (README,
#           "Real scenes", says where each public dataset lives); the cow is built in
#   OUT     the study folder (run folders; large, not committed)
#   TABLE   a working copy of docs/results/real-study-table.json (resuming from it skips every
#           recorded run); the frozen code may not know row fields added later, so drop them:
#           python3 -c "import json,sys; t=json.load(open(sys.argv[1])); [r.pop('uniform_fill', None) for r in t['runs']]; json.dump(t, open(sys.argv[2], 'w'))" docs/results/real-study-table.json "$TABLE"
#   NERFAUG the nerfaug entry point of an environment with the project's dependencies
#   WITH_CPU 1 to go on with the plan's optional engine, `cpu`, after both (the four scenes, then
#           the held-back one), once every cell of the two planned engines is complete
#
# Afterwards, from main: `nerfaug study --summary-only --out OUT --table
# docs/results/real-study-table.json --results-doc docs/results-real.md` records the new runs in
# the committed table and regenerates the page; the reading on it is written by hand.
set -euo pipefail
: "${FROZEN:?}" "${DATA:?}" "${OUT:?}" "${TABLE:?}" "${NERFAUG:=nerfaug}"
cd "$FROZEN"
export PYTHONPATH="$FROZEN/src"
METHODS="uniform ours ours-paper-sum ours-batch-sharp fisherrf fisherrf-sampling entropy-sampling furthest"
cell() {  # engine scene
    nice -n 19 "$NERFAUG" study --out "$OUT" --table "$TABLE" --engines "$1" --scenes "$2" \
        --methods $METHODS --trials 10 --resolution 100 --device auto --preset study --layouts 3
}
for engine in nerfacto-cpu nerfacto-cpu-last-sample; do
    for scene in "$DATA/mic" "$DATA/maryRose" "$DATA/dtu_scan24" cow; do
        cell "$engine" "$scene"
    done
done
# Held back for replication: run only once every cell above is complete.
for engine in nerfacto-cpu nerfacto-cpu-last-sample; do
    cell "$engine" "$DATA/moldGoldCape"
done
if [ "${WITH_CPU:-0}" = 1 ]; then
    for scene in "$DATA/mic" "$DATA/maryRose" "$DATA/dtu_scan24" cow "$DATA/moldGoldCape"; do
        cell cpu "$scene"
    done
fi
