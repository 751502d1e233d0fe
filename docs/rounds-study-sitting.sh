#!/usr/bin/env bash
# One sitting of the study of rounds (docs/study-plan.md, "Plan of 2026-11-28: the study of rounds"
# and its amendments): its arms in the plan's order, each resumed where its folder and table leave
# it, so a sitting can stop anywhere and the next one goes on. Record the sitting in
# docs/study-plan.md before starting it.
#
#   FROZEN  a checkout of the study's frozen code (its runs' fingerprints must match the tables';
#           `git worktree add --detach FROZEN 442f736`, the commit of the first sitting, or a later
#           one a sitting's entry names)
#   DATA    the prepared scenes: for each of mic, maryRose, dtu_scan24, moldGoldCape,
#           `nerfaug scene prepare DOWNLOADS/<scene> --out DATA/<scene> --width 100` (README,
#           "Real scenes"); the cow is built in
#   OUT     where the two study folders go: OUT/rounds (the runs in rounds), OUT/rounds-oneshot (the
#           one-shot arm); large, not committed
#   NERFAUG the nerfaug entry point of an environment with the project's dependencies
#
# Order: the rounds arm on the four scenes, then the one-shot arm on them, then the held-back
# moldGoldCape (both arms). A stage that leaves a failed run stops the sitting (`nerfaug study`
# exits 1): a failed run is an error, run again, never a result.
#
# Afterwards, from main, the committed tables and the page:
#   nerfaug study --summary-only --out OUT/rounds-oneshot --table docs/results/rounds-oneshot-table.json --hypotheses none
#   nerfaug study --summary-only --out OUT/rounds --table docs/results/rounds-study-table.json \
#       --hypotheses rounds --one-shot-table docs/results/rounds-oneshot-table.json --results-doc docs/results-rounds.md
set -euo pipefail
: "${FROZEN:?}" "${DATA:?}" "${OUT:?}" "${NERFAUG:=nerfaug}"
cd "$FROZEN"
export PYTHONPATH="$FROZEN/src"
arm() {  # rounds|oneshot scene...
    local which=$1
    shift
    if [ "$which" = rounds ]; then
        set -- --out "$OUT/rounds" --methods uniform ours ours-batch-sharp fisherrf entropy-sampling furthest \
            --n-initial 4 --n-new 1 --add-at-step 200 --rounds 8 --round-every 100 --hypotheses rounds --scenes "$@"
    else
        set -- --out "$OUT/rounds-oneshot" --methods uniform ours --hypotheses none --scenes "$@"
    fi
    "$NERFAUG" study --engines nerfacto-cpu --trials 10 --layouts 3 --resolution 100 --preset study "$@"
}
arm rounds "$DATA/mic" "$DATA/maryRose" "$DATA/dtu_scan24" cow
arm oneshot "$DATA/mic" "$DATA/maryRose" "$DATA/dtu_scan24" cow
# Held back for replication: run only once every cell above is complete.
arm rounds "$DATA/moldGoldCape"
arm oneshot "$DATA/moldGoldCape"
