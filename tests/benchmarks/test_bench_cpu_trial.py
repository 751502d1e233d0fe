"""benchmarks/bench_cpu_trial.py compares today's engine with an earlier commit's: the earlier
engine is that commit's own source, and losses are compared step by step."""

import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_cpu_trial.py"


def test_the_baseline_is_the_earlier_commits_own_engine(bench, tmp_path):
    root = SCRIPT.parents[1]
    if subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD~1"], capture_output=True).returncode:
        pytest.skip("needs a git checkout with history")
    source = bench.export_source("HEAD~1", tmp_path)
    expected = subprocess.run(
        ["git", "-C", str(root), "show", "HEAD~1:src/nerfaug/nerf/encoding.py"], capture_output=True, text=True
    ).stdout
    assert (source / "nerfaug" / "nerf" / "encoding.py").read_text() == expected


def test_losses_are_compared_step_by_step(bench):
    assert bench.largest_difference([0.5, 0.25], [0.5, 0.25]) == 0.0
    assert bench.largest_difference([0.5, 0.25], [0.5, 0.2500001]) == pytest.approx(1e-7)
    assert bench.largest_difference([0.5], [0.5, 0.25]) == float("inf")  # a run that stopped early
