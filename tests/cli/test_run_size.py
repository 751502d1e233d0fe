"""The size line `nerfaug run` and `nerfaug study` print before they start: the run count and its
shape, the image size, and a time estimate whose model agrees with what BENCHMARKS.md measured."""

from pathlib import Path

import pytest

from nerfaug.cli import run_size
from nerfaug.cli.run_size import (
    RunKind,
    SceneSize,
    duration,
    estimate,
    render_seconds,
    run_seconds,
    scene_sizes,
    size_line,
)
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


# The study of rounds (docs/study-plan.md): nerfacto-cpu, 2000 steps, 4 initial views + 8 rounds of
# one, 50 test views at 100 px, no uncertainty figures.
ROUNDS = STUDY_PRESETS["study"].replace(
    device="cpu", engine="nerfacto-cpu", n_initial=4, n_new=1, rounds=8, round_every=100, view_uncertainty=False
)
MIC = SceneSize("mic", pool=96, test=50, pixels=100 * 100)
DTU = SceneSize("dtu_scan24", pool=33, test=12, pixels=100 * 75)


def test_a_run_is_costed_at_its_engine_versions_speed_on_its_scenes_own_pool_and_views():
    # By hand from BENCHMARKS.md's nerfacto-cpu costs (0.065 s a step, 0.6 s a 100x100 test view,
    # 7.4 s / 28 s to score 100 candidates with ours / FisherRF, 1.5 s of setup and files) and the
    # fused hash loop's 1.61x: each round scores the scene's own candidates, 8 curve points of
    # min(8, test views) and the scene's test views at its own pixels.
    reference_uniform = 2000 * 0.065 + 50 * 0.6 + 8 * 8 * 0.6 + 1.5
    assert run_seconds("nerfacto-cpu", "none", ROUNDS) == pytest.approx(reference_uniform)
    ours_on_mic = (2000 * 0.065 + 8 * 7.4 * 96 / 100 + 50 * 0.6 + 8 * 8 * 0.6) / 1.61 + 1.5
    assert run_seconds("nerfacto-cpu", "combined", ROUNDS, "hash-cpu-1", MIC) == pytest.approx(ours_on_mic)
    view = 0.6 * 0.75  # 100x75 pixels
    fisher_on_dtu = (2000 * 0.065 + 8 * 28.0 * 33 / 100 + 12 * view + 8 * 8 * view) / 1.61 + 1.5
    assert run_seconds("nerfacto-cpu", "fisher", ROUNDS, "hash-cpu-1", DTU) == pytest.approx(fisher_on_dtu)
    # An engine version not measured runs at the reference's speed; the scene's size alone changes
    # only what depends on it.
    assert run_seconds("nerfacto-cpu", "none", ROUNDS, "unmeasured", MIC) == pytest.approx(reference_uniform)
    # A pair and its RunKind of the reference engine on the config's scene are one thing.
    pair = {("nerfacto-cpu", "fisher"): 3}
    assert estimate(pair, ROUNDS, 1) == estimate({RunKind("nerfacto-cpu", "fisher"): 3}, ROUNDS, 1)


def test_the_study_of_rounds_is_estimated_within_1_5x_of_its_mic_runs(two_cores):
    # The study of rounds' first 25 runs, mic, two at a time on the 2-core VM shared with other work
    # (load 4-5; BENCHMARKS.md "The time estimate of the study of rounds against its mic runs"):
    # timing.total 191 s a run on average over the six methods. The estimate before it
    # (the reference engine, lego's 300 candidates for every scene) said 401 s.
    # uniform, ours, ours-batch-sharp, fisherrf, entropy-sampling, furthest: 10 trials each.
    methods = ("none", "combined", "combined", "fisher", "entropy", "none")
    runs: dict[RunKind, int] = {}
    for scoring in methods:
        kind = RunKind("nerfacto-cpu", scoring, "hash-cpu-1", MIC)
        runs[kind] = runs.get(kind, 0) + 10
    seconds, _ = estimate(runs, ROUNDS, workers=2)
    per_run = seconds * 2 / 60  # two at a time on the two cores
    assert 191 / 1.5 <= per_run <= 191 * 1.5
    old = sum(run_seconds("nerfacto-cpu", scoring, ROUNDS) for scoring in methods) / len(methods)
    assert old > 191 * 1.5  # what this corrects


def test_dataset_scenes_sizes_come_from_the_sweeps_check(tmp_path):
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.data import Views, write_blender_split
    from nerfaug.experiment.sweep import check_config
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

    folder, generator = tmp_path / "toy", torch.Generator().manual_seed(0)
    for split, n in (("train", 14), ("test", 5)):
        cameras = Cameras.from_fov(sample_uniform_poses(n, generator), BLENDER_CAMERA_ANGLE_X, 16, 12)
        write_blender_split(folder, split, Views(cameras, torch.rand(n, 12, 16, 3), [f"r_{i}" for i in range(n)]))
    config = PROTOCOL_PRESETS.choose("tiny").replace(
        scenes=(str(folder), "lego"), resolution=16, n_initial=4, n_test=5, pool=40, methods=("uniform", "ours")
    )
    checked = check_config(config)
    # 14 training views less the 4 initial ones are the candidates; a built-in scene follows the config.
    assert scene_sizes(checked) == {"toy": SceneSize("toy", pool=10, test=5, pixels=16 * 12)}
    runs, finished = runs_to_do(config, tmp_path / "results", checked=checked)
    version, trials = config.engine_version(), config.trials
    size = SceneSize("toy", 10, 5, 16 * 12)
    assert finished == 0 and runs == {
        RunKind(str(config.engine), "none", version, size): trials,
        RunKind(str(config.engine), "combined", version, size): trials,
        RunKind(str(config.engine), "none", version, None): trials,
        RunKind(str(config.engine), "combined", version, None): trials,
    }


def test_the_size_line_says_what_it_assumed_beyond_the_config(two_cores):
    runs = {
        RunKind("nerfacto-cpu", "fisher", "hash-cpu-1", MIC): 10,
        RunKind("nerfacto-cpu", "none", "hash-cpu-1", DTU): 10,
    }
    line = size_line("nerfaug study", runs, 0, "2 scenes x 2 methods x 5 trials", ROUNDS, 2)
    assert line.endswith(
        "An estimate from the costs measured in BENCHMARKS.md (engine version hash-cpu-1 at 1.61x the "
        "reference engine's speed; candidates scored a round: mic 96, dtu_scan24 33): a busy machine takes longer."
    )
    # Nothing is said where nothing but the config was read, nor pools where no method scores.
    plain = size_line("nerfaug run", {("nerfacto-cpu", "none"): 4}, 0, "1 scene", ROUNDS, 2)
    assert plain.endswith("An estimate from the costs measured in BENCHMARKS.md: a busy machine takes longer.")
    unscored = size_line("nerfaug run", {RunKind("nerfacto-cpu", "none", None, MIC): 4}, 0, "1 scene", ROUNDS, 2)
    assert "candidates" not in unscored and "(" not in unscored.split("BENCHMARKS.md")[1]


def test_durations_read_as_a_person_says_them():
    assert [duration(s) for s in (5, 600, 4 * 3600, 5 * 86400)] == ["5 s", "10 min", "4.0 h", "5.0 days"]
