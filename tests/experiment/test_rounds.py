"""Schedules of rounds: a run adds views in rounds, each chosen with the model trained on the views
so far, and records each round (its views, scoring time, test metrics after it); one round is the
paper's protocol, whose record and fingerprint are as they were."""

import json

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.experiment import protocol
from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig
from nerfaug.experiment.runfolder import FILES
from nerfaug.experiment.store import RunKey, fingerprint
from nerfaug.experiment.sweep import check_config
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SIZE = 16


@pytest.fixture(scope="module")
def toy_data(tmp_path_factory):
    """A Blender-format toy scene: 12 candidates, 3 test views, 3 initial views (random images)."""
    folder = tmp_path_factory.mktemp("toy") / "data"
    generator = torch.Generator().manual_seed(0)
    for split, n in (("train", 12), ("test", 3), ("initial", 3)):
        cameras = Cameras.from_fov(sample_uniform_poses(n, generator), BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
        images = torch.rand(n, SIZE, SIZE, 3, generator=generator)
        write_blender_split(folder, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))
    return folder


def tiny(**changes) -> ExperimentConfig:
    config = PROTOCOL_PRESETS.choose("tiny").replace(steps=40, add_at_step=10, round_every=10, n_test=3)
    config = config.replace(resolution=SIZE, view_uncertainty=False, hemisphere_map=False, save_renders=0)
    return config.replace(**changes)


# What a run's result.json held before schedules of rounds: a run of one round holds exactly this.
ONE_ROUND_FIELDS = {
    "scene", "method", "trial", "seed", "fingerprint", "code_version", "metrics", "lpips_status", "chosen",
    "layout", "views", "timing", "host", "torch", "device", "health",
}  # fmt: skip
ONE_ROUND_TIMING = {"setup", "train_before", "selection", "oracle", "train_after", "evaluation", "total"}


def test_three_rounds_of_one_view_record_growing_views_and_metrics_after_each(toy_data, tmp_path, monkeypatch):
    seen = []
    original = protocol.select_views

    def counting(method, model, train_cameras, candidates, *args, **kwargs):
        seen.append((len(train_cameras), len(candidates)))
        return original(method, model, train_cameras, candidates, *args, **kwargs)

    monkeypatch.setattr(protocol, "select_views", counting)
    config = tiny(rounds=3, n_new=1, round_every=10)
    key = RunKey("scene", "entropy", 0)
    result = protocol.run_trial(key, toy_data, config, tmp_path)

    # Each round chose among the candidates left, conditioned on every view the model had then.
    assert seen == [(3, 12), (4, 11), (5, 10)]
    rounds = result["rounds"]
    assert [r["round"] for r in rounds] == [1, 2, 3]
    assert [r["step"] for r in rounds] == [10, 20, 30]
    assert [r["views"] for r in rounds] == [4, 5, 6]
    assert result["before_rounds"]["views"] == 3 and result["before_rounds"]["step"] == 10
    chosen = [i for r in rounds for i in r["chosen"]]
    assert chosen == result["chosen"] and len(set(chosen)) == 3
    names = json.loads((key.folder(tmp_path) / FILES.selection).read_text())["chosen_names"]
    assert names == [n for r in rounds for n in r["names"]]
    for r in rounds:
        assert r["selection_s"] >= 0 and 0 <= r["metrics"]["psnr"] < 100 and "ssim" in r["metrics"]
    # Between rounds on the curve's test views (all three here: at most 8); the last is the run's evaluation.
    assert [r["metrics_step"] for r in rounds] == [20, 30, 40]
    assert rounds[-1]["metrics"] == result["metrics"] and rounds[-1]["test_views"] == 3
    assert result["timing"]["curve"] > 0
    assert result["timing"]["selection"] == pytest.approx(sum(r["selection_s"] for r in rounds))
    history = json.loads((key.folder(tmp_path) / FILES.history).read_text())
    assert history  # trained to the end


def test_one_round_keeps_the_record_and_fingerprint_it_always_had(toy_data, tmp_path):
    config = tiny()
    assert config.rounds == 1
    result = protocol.run_trial(RunKey("scene", "uniform", 0), toy_data, config, tmp_path)
    assert set(result) == ONE_ROUND_FIELDS
    assert set(result["timing"]) == ONE_ROUND_TIMING
    assert len(result["chosen"]) == config.n_new
    fingerprinted = config.fingerprinted()
    assert "rounds" not in fingerprinted and "round_every" not in fingerprinted
    # With one round the gap between rounds changes nothing, so it moves no fingerprint.
    assert fingerprint(config.replace(round_every=7).fingerprinted()) == fingerprint(fingerprinted)
    assert fingerprint(config.replace(rounds=2).fingerprinted()) != fingerprint(fingerprinted)


@pytest.mark.parametrize(
    ("changes", "refusal"),
    [
        ({"rounds": 7, "round_every": 1}, "--rounds 7: 7 rounds of --n-new 2 add 14 views, more than the 12"),
        ({"rounds": 4, "round_every": 10}, "--rounds 4: the last round would come at step 40"),
        ({"rounds": 0}, "--rounds 0: must be >= 1"),
        ({"rounds": 2, "round_every": 0}, "--round-every 0: must be >= 1"),
        ({"rounds": 2.0}, "--rounds 2.0: Input should be a valid integer"),
    ],
)
def test_impossible_schedules_are_refused_in_one_line_naming_the_option(toy_data, changes, refusal):
    with pytest.raises(ValueError) as caught:
        check_config(tiny(scenes=(str(toy_data),), **changes))
    assert str(caught.value).startswith(refusal) and "\n" not in str(caught.value)


def test_a_built_in_scenes_pool_bounds_the_views_all_rounds_add():
    with pytest.raises(ValueError, match=r"^--rounds 5: 5 rounds of --n-new 3 add 15 views, more than the 12"):
        check_config(tiny(rounds=5, n_new=3, round_every=5, scenes=("lego",)))


def test_rounds_are_checked_at_any_batch_size(toy_data):
    """Runs of several rounds train in batches as alone: a batch passes the check a run alone passes."""
    check_config(tiny(scenes=(str(toy_data),), rounds=2, round_every=5, batch=2, engine="nerfacto-cpu"))


def test_the_time_estimate_covers_every_rounds_scoring_and_curve():
    from nerfaug.cli.run_size import run_seconds, size_line
    from nerfaug.experiment.config import STUDY_PRESETS

    one = STUDY_PRESETS["study"].replace(device="cpu", n_initial=4, n_new=1)
    eight = one.replace(rounds=8)
    # nerfacto-cpu's costs (BENCHMARKS.md): FisherRF scores 100 candidates in 28 s, a test view
    # takes 0.6 s; seven more scorings of the 300-view pool and 8 curve points of 8 test views.
    assert run_seconds("nerfacto-cpu", "fisher", eight) - run_seconds("nerfacto-cpu", "fisher", one) == pytest.approx(
        7 * 28.0 * 3 + 8 * 8 * 0.6
    )
    line = size_line("nerfaug run", {("nerfacto-cpu", "fisher"): 1}, 0, "1 scene", eight, 1)
    assert "2000 steps each, 4 initial views + 8 rounds of 1 with the nerfacto-cpu engine;" in line


def test_run_and_study_take_the_schedule_on_the_command_line(monkeypatch, toy_data, tmp_path):
    import nerfaug.cli.run_work as run_work
    import nerfaug.experiment.study as study_module
    from nerfaug.cli import main
    from nerfaug.experiment.study_spec import StudySpec

    taken = []
    monkeypatch.setattr(run_work, "run", lambda protocol, out, **_: taken.append(protocol))
    schedule = ["--n-initial", "4", "--n-new", "1", "--add-at-step", "20", "--rounds", "3", "--round-every", "10"]
    main(["run", "--preset", "tiny", "--out", str(tmp_path / "r"), *schedule])
    (protocol,) = taken
    assert (protocol.n_initial, protocol.n_new, protocol.add_at_step, protocol.rounds, protocol.round_every) == (
        4,
        1,
        20,
        3,
        10,
    )

    monkeypatch.setattr(study_module, "prepare_datasets", lambda *args, **kwargs: {})
    spec = StudySpec(
        out=tmp_path / "s", engines=("test",), scenes=(str(toy_data),), methods=("uniform",), trials=1, device="cpu",
        preset="tiny", resolution=SIZE, n_initial=3, n_new=1, add_at_step=20, rounds=3, round_every=10,
    )  # fmt: skip
    config = study_module.make_plan(spec, spec.command(), progress=False).config
    assert (config.n_initial, config.n_new, config.add_at_step, config.rounds, config.round_every) == (3, 1, 20, 3, 10)
    assert spec.command()[-10:] == [
        "--n-initial", "3", "--n-new", "1", "--add-at-step", "20", "--rounds", "3", "--round-every", "10",
    ]  # fmt: skip
    # A study of one round plans as it did: none of the schedule's options in its command.
    assert "--rounds" not in StudySpec(preset="tiny").command()


# A batch of runs against the same runs alone: rounding that a CPU's kernels move (`make test-rounding`).
@pytest.mark.rounding
@pytest.mark.parametrize("engine", ["test", "nerfacto-cpu"])
def test_a_batch_of_trials_records_what_each_run_records_alone(toy_data, tmp_path, engine):
    """Runs of several rounds trained as one batch choose the same views and reach the same
    metrics as each alone, with the same fingerprint; the record adds only the batch's size."""
    config = tiny(rounds=2, n_new=2, round_every=10, steps=30, engine=engine)
    keys = [RunKey("scene", "uniform", 0), RunKey("scene", "entropy", 1)]
    together = protocol.run_trials(keys, {"scene": toy_data}, config.replace(batch=2), tmp_path / "batch")
    for key in keys:
        alone = protocol.run_trial(key, toy_data, config.replace(batch=1), tmp_path / "alone")
        batched = together[key]
        assert batched["chosen"] == alone["chosen"] and batched["fingerprint"] == alone["fingerprint"]
        numbers = {name for name, value in alone["metrics"].items() if value is not None}  # LPIPS: no weights here
        assert numbers >= {"psnr", "ssim"} and batched["metrics"].keys() == alone["metrics"].keys()
        assert {n: batched["metrics"][n] for n in numbers} == pytest.approx(
            {n: alone["metrics"][n] for n in numbers}, rel=1e-5
        )
        assert [r["chosen"] for r in batched["rounds"]] == [r["chosen"] for r in alone["rounds"]]
        assert batched["batch_size"] == 2 and "batch_size" not in alone
        assert batched.keys() - alone.keys() == {"batch_size"}
    assert together[keys[0]]["metrics"] != together[keys[1]]["metrics"]


def test_a_failing_run_of_a_batch_fails_alone(toy_data, tmp_path, monkeypatch):
    original = protocol.select_views

    def failing(method, *args, **kwargs):
        if method == "entropy":
            raise RuntimeError("this method broke")
        return original(method, *args, **kwargs)

    monkeypatch.setattr(protocol, "select_views", failing)
    keys = [RunKey("scene", "uniform", 0), RunKey("scene", "entropy", 0)]
    outcomes = protocol.run_trials(keys, {"scene": toy_data}, tiny(steps=20, batch=2), tmp_path)
    assert isinstance(outcomes[keys[1]], RuntimeError) and outcomes[keys[0]]["method"] == "uniform"
    # Alone, the run's failure is raised.
    with pytest.raises(RuntimeError, match="this method broke"):
        protocol.run_trial(keys[1], toy_data, tiny(steps=20), tmp_path / "alone")


def test_a_batch_trains_with_the_compile_setting_it_is_fingerprinted_with(toy_data, tmp_path, monkeypatch):
    built = []

    class Recording(protocol.Trainer):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            built.append(self)

    monkeypatch.setattr(protocol, "Trainer", Recording)
    keys = [RunKey("scene", "uniform", 0), RunKey("scene", "uniform", 1)]
    config = tiny(steps=12, add_at_step=6, batch=2, compile="eager")
    outcomes = protocol.run_trials(keys, {"scene": toy_data}, config, tmp_path)
    assert all(isinstance(outcome, dict) for outcome in outcomes.values())
    (trainer,) = built
    assert len(trainer) == 2 and trainer.compile_backend == "eager"
    assert all(run.model.field._compiled_call_impl is not None for run in trainer.runs)
