"""benchmarks/acceptance_summary.py: the planned TOST of both arms passed through as recorded,
the |d| summaries and the exploratory rank-sum computed as scipy computes them."""

import json
from pathlib import Path

import pytest
from scipy import stats

from nerfaug.equivalence import paired_equivalence

SCRIPT = Path(__file__).parents[2] / "benchmarks" / "acceptance_summary.py"


def arm(path: Path, key: str, differences: list[float]) -> list[float]:
    reference = [25.0 + i for i in range(len(differences))]
    runs = [
        {"scene": "lego" if i % 2 else "chair", "trial": i, "psnr_alone": r, key: r + d, "difference": d}
        for i, (r, d) in enumerate(zip(reference, differences))
    ]
    after = [r + d for r, d in zip(reference, differences)]
    path.write_text(json.dumps({"runs": runs, "equivalence": paired_equivalence(after, reference, 0.2)}))
    return differences


def test_both_arms_are_judged_and_their_spreads_compared(bench, tmp_path, capsys):
    candidate = arm(tmp_path / "c.json", "psnr_candidate", [0.01, -0.02, 0.03, -0.01, 0.0, 0.02])
    null = arm(tmp_path / "n.json", "psnr_nudged", [0.5, -0.9, 1.2, -0.4, 0.7, -2.0])
    out = tmp_path / "s.json"
    assert bench.main([str(tmp_path / "c.json"), str(tmp_path / "n.json"), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["accepted"] and not result["null"]["tost"]["equivalent"]
    assert result["candidate"]["unchanged_runs"] == 1 and result["null"]["max_abs_d"] == pytest.approx(2.0)
    assert result["null"]["median_abs_d"] == pytest.approx(0.8)
    expected = stats.mannwhitneyu([abs(x) for x in candidate], [abs(x) for x in null], alternative="two-sided")
    assert result["abs_d_candidate_vs_null_ranksum_p"] == pytest.approx(expected.pvalue)
    assert "null: mean d" in capsys.readouterr().out
