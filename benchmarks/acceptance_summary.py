"""The acceptance of a new CPU engine version, summarised from its arms (docs/study-plan.md,
"acceptance of a new CPU engine version"): the candidate's paired differences from the reference
and the rounding null's, each by the planned TOST, and (exploratory, as planned) whether the
candidate's |d| are larger than the null's (Mann-Whitney / Wilcoxon rank-sum, two-sided).

    python benchmarks/acceptance_summary.py CANDIDATE.json NULL.json [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

from scipy import stats


def summary(runs: list[dict], key: str, equivalence: dict) -> dict:
    """Median and largest |d|, mean d per scene and the TOST of one arm's paired differences."""
    d = [r["difference"] for r in runs]
    scenes = sorted({r["scene"] for r in runs})
    return {
        "tost": equivalence,
        "median_abs_d": statistics.median(abs(x) for x in d),
        "max_abs_d": max(abs(x) for x in d),
        "mean_d_per_scene": {s: statistics.mean(r["difference"] for r in runs if r["scene"] == s) for s in scenes},
        "unchanged_runs": sum(x == 0.0 for x in d),
        "arm": key,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("candidate", type=Path)
    parser.add_argument("null", type=Path)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    candidate, null = json.loads(args.candidate.read_text()), json.loads(args.null.read_text())
    result = {
        "candidate": summary(candidate["runs"], "psnr_candidate", candidate["equivalence"]),
        "candidate_engine_versions": candidate.get("engine_versions"),
        "null": summary(null["runs"], "psnr_nudged", null["equivalence"]),
        "null_nudge": null.get("nudge"),
    }
    cand_abs = [abs(r["difference"]) for r in candidate["runs"]]
    null_abs = [abs(r["difference"]) for r in null["runs"]]
    test = stats.mannwhitneyu(cand_abs, null_abs, alternative="two-sided")
    result["abs_d_candidate_vs_null_ranksum_p"] = float(test.pvalue)
    result["accepted"] = bool(candidate["equivalence"]["equivalent"])
    for name in ("candidate", "null"):
        s, t = result[name], result[name]["tost"]
        print(
            f"{name}: mean d {t['mean']:+.3f} dB, 90% CI [{t['low']:+.3f}, {t['high']:+.3f}], TOST p {t['p_value']:.3f}"
            f" ({'equivalent' if t['equivalent'] else 'not shown equivalent'}); median |d| {s['median_abs_d']:.3f},"
            f" largest |d| {s['max_abs_d']:.3f} dB; per scene "
            + ", ".join(f"{k} {v:+.3f}" for k, v in s["mean_d_per_scene"].items())
        )
    print(f"|d| candidate vs null, rank-sum (exploratory): p = {result['abs_d_candidate_vs_null_ranksum_p']:.3f}")
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
