"""The size line `nerfaug run` and `nerfaug study` print before they start: the run count and its
shape, the image size, and a time estimate whose model agrees with what BENCHMARKS.md measured."""

import pytest

from nerfaug.cli.run_size import duration, run_seconds, size_line


def test_the_cost_model_agrees_with_the_measured_runs():
    # `make demo` on a quiet machine (BENCHMARKS.md, "Demo"): 760 s of CPU for 20 quick runs
    # (800 steps, 20 test views at 100 px) plus install, render and report: at most 38 s per run.
    assert 25 <= run_seconds("cpu", "cpu", 800, 20, 100) <= 38
    # One H100 ("GPU: the paper preset"): 361 s for a 10k-step run with 200 test views at 400 px.
    assert run_seconds("paper", "cuda", 10_000, 200, 400) == pytest.approx(361, rel=0.2)
    # nerfacto-cpu ("nerfacto-CPU preset"): 117-145 s of CPU for a 2000-step, 50-view trial.
    assert 100 <= run_seconds("nerfacto-cpu", "cpu", 2000, 50, 100) <= 160
    # An engine variant costs what its base does.
    assert run_seconds("cpu+lr=0.005", "cpu", 100, 1, 100) == run_seconds("cpu", "cpu", 100, 1, 100)


def test_the_size_line_says_runs_resolution_and_that_it_is_an_estimate():
    line = size_line("nerfaug run", {"cpu": 18}, 2, "1 scene x 4 methods x 5 trials", 100, 800, 20, "cpu", 2)
    assert line.startswith("nerfaug run: 20 runs (1 scene x 4 methods x 5 trials, 2 already finished), 100x100 pixels")
    assert "18 to run: about " in line and "on this device (cpu, 2 runs at a time" in line
    assert "estimate" in line and "\n" not in line
    # Two workers halve the time of many runs.
    one = size_line("nerfaug run", {"cpu": 40}, 0, "x", 100, 2000, 50, "cpu", 1)
    two = size_line("nerfaug run", {"cpu": 40}, 0, "x", 100, 2000, 50, "cpu", 2)
    assert "about 48 min" in one and "about 24 min" in two


def test_durations_read_as_a_person_says_them():
    assert [duration(s) for s in (5, 600, 4 * 3600, 5 * 86400)] == ["5 s", "10 min", "4.0 h", "5.0 days"]
