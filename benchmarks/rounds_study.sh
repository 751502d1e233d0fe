#!/bin/bash
# The study of rounds (docs/study-plan.md, "Plan of 2026-11-28: the study of rounds" and its
# amendments), in resumable sittings: run it again and it goes on where it stopped.
#
#   bash benchmarks/rounds_study.sh DATA [OUT]
#
# DATA holds the prepared real scenes (README, "Real scenes"): DATA/mic, DATA/maryRose,
# DATA/dtu_scan24 and, held back, DATA/moldGoldCape; the cow is built in. OUT (default results)
# receives the run folders: OUT/rounds (the runs in rounds), OUT/rounds-oneshot (the one-shot arm).
# The tables go to docs/results/, the page to docs/results-rounds.md.
#
# Order, as the plan fixes it: the rounds arm on the four scenes, then the one-shot arm on them,
# then the held-back moldGoldCape (both arms). A stage that leaves a failed run stops the script
# (`nerfaug study` exits 1): a failed run is an error, run again, never a result.
set -euo pipefail
data=${1:?usage: bash benchmarks/rounds_study.sh DATA [OUT]}
out=${2:-results}
nerfaug=${NERFAUG:-nerfaug}
scenes=("$data/mic" "$data/maryRose" "$data/dtu_scan24" cow)
common=(--engines nerfacto-cpu --trials 10 --layouts 3 --resolution 100)
rounds=(--out "$out/rounds" --table docs/results/rounds-study-table.json
  --methods uniform ours ours-batch-sharp fisherrf entropy-sampling furthest
  --n-initial 4 --n-new 1 --add-at-step 200 --rounds 8 --round-every 100 --hypotheses rounds)
oneshot=(--out "$out/rounds-oneshot" --table docs/results/rounds-oneshot-table.json
  --methods uniform ours --hypotheses none)

$nerfaug study "${common[@]}" "${rounds[@]}" --scenes "${scenes[@]}"
$nerfaug study "${common[@]}" "${oneshot[@]}" --scenes "${scenes[@]}"
$nerfaug study "${common[@]}" "${rounds[@]}" --scenes "$data/moldGoldCape"
$nerfaug study "${common[@]}" "${oneshot[@]}" --scenes "$data/moldGoldCape"
$nerfaug study --summary-only --out "$out/rounds" --table docs/results/rounds-study-table.json \
  --hypotheses rounds --one-shot-table docs/results/rounds-oneshot-table.json \
  --results-doc docs/results-rounds.md
