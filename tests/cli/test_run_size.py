"""The size line `nerfaug run` and `nerfaug study` print before they start: the run count and its
shape, the image size, and a time estimate whose model agrees with what BENCHMARKS.md measured."""

from pathlib import Path

import pytest

from nerfaug.cli import run_size
from nerfaug.cli.run_size import duration, estimate, render_seconds, run_seconds, size_line
from nerfaug.cli.run_work import runs_to_do
from nerfaug.experiment.config import PROTOCOL_PRESETS, STUDY_PRESETS

QUICK = PROTOCOL_PRESETS.choose("quick", device="cpu")


@pytest.fixture
def two_cores(monkeypatch):
    """The project's 2-core VM, where the costs were measured."""
    monkeypatch.setattr(run_size.os, "cpu_count", lambda: 2)


def test_the_cost_model_agrees_with_the_measured_runs():
    # The idle demo's runs ("The demo's time estimate against its time"): uniform 67-73 s,
    # FisherRF 93-100 s (the phases its records time, two runs side by side).
    assert 60 <= run_seconds("cpu", "none", QUICK) <= 80
    assert 85 <= run_seconds("cpu", "fisher", QUICK) <= 110
    # One H100 ("GPU: the paper preset"): 361 s for ours in a 10k-step run with 200 test views at 400 px.
    gpu = QUICK.replace(device="cuda", steps=10_000, n_test=200, resolution=400, pool=500)
    assert run_seconds("paper", "combined", gpu) == pytest.approx(361, rel=0.2)
    # nerfacto-cpu ("Trial batches on the CPU", the arm alone): 130 s of training and 31.6 s of
    # evaluation for a uniform run of the study's protocol.
    study = STUDY_PRESETS["study"].replace(device="cpu")
    assert run_seconds("nerfacto-cpu", "none", study) == pytest.approx(162, rel=0.2)
    # An engine variant costs what its base does.
    assert run_seconds("cpu+lr=0.005", "combined", QUICK) == run_seconds("cpu", "combined", QUICK)


def test_the_demo_is_estimated_within_1_5x_of_its_measured_time(two_cores):
    # `nerfaug run --preset quick` on the idle 2-core VM took 13 min 42 s, the render (28 s) included
    # ("The demo's time estimate against its time"); the costs before that section gave 6.7 min.
    runs, finished = runs_to_do(QUICK, Path("no-results-here"))
    assert (sum(runs.values()), finished) == (20, 0)
    seconds, _ = estimate(runs, QUICK, workers=2)
    views = QUICK.pool + QUICK.n_test + QUICK.n_initial
    measured = 13.7 * 60
    assert measured / 1.5 <= seconds <= measured * 1.5
    assert measured / 1.5 <= seconds + render_seconds(views, QUICK.resolution) <= measured * 1.5


def test_what_a_run_does_is_counted(two_cores):
    def minutes(config):
        return estimate(runs_to_do(config, Path("no-results-here"))[0], config, workers=2)[0]

    # uniform chooses without scoring the candidates; ours renders every candidate's entropy.
    assert minutes(QUICK.replace(methods=("uniform",))) < minutes(QUICK.replace(methods=("ours",)))
    assert minutes(QUICK.replace(methods=("ours",))) < minutes(QUICK.replace(methods=("fisherrf",)))
    # The uncertainty figures cost seconds per run, a larger pool more scoring.
    assert minutes(QUICK.replace(view_uncertainty=False)) < minutes(QUICK)
    assert minutes(QUICK.replace(pool=300)) > minutes(QUICK)


def test_the_size_line_says_runs_resolution_and_that_it_is_an_estimate(two_cores):
    line = size_line("nerfaug run", {("cpu", "combined"): 18}, 2, "1 scene x 4 methods x 5 trials", QUICK, 2)
    assert line.startswith("nerfaug run: 20 runs (1 scene x 4 methods x 5 trials, 2 already finished), 100x100 pixels")
    assert "18 to run: about " in line and "on this device (cpu, 2 runs at a time on 2 cores)" in line
    assert "estimate" in line and "\n" not in line
    assert "800 steps each with the cpu engine; 18 to run" in line  # `nerfaug train`'s default engine is another
    study = size_line("nerfaug study", {("cpu", "none"): 2, ("nerfacto-cpu", "none"): 2}, 0, "2 engines", QUICK, 2)
    assert "with the cpu and nerfacto-cpu engines; " in study
    # Two workers halve the time of many runs; more workers than cores do not go faster.
    runs = {("cpu", "none"): 40}
    one, two, four = (estimate(runs, QUICK, workers)[0] for workers in (1, 2, 4))
    assert two == pytest.approx(one / 2) and four == two


def test_durations_read_as_a_person_says_them():
    assert [duration(s) for s in (5, 600, 4 * 3600, 5 * 86400)] == ["5 s", "10 min", "4.0 h", "5.0 days"]
