"""Steps between rounds that grow with the views (`--round-growth per-view`, as FisherRF's schedule
trains longer as views are added): the rounds' steps, the refusal naming the rule, a run that
follows them, and the fingerprint rule (the default moves no recorded fingerprint)."""

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.experiment import protocol
from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig
from nerfaug.experiment.schedule import round_steps
from nerfaug.experiment.store import RunKey, fingerprint
from nerfaug.experiment.study_spec import StudySpec
from nerfaug.experiment.sweep import check_config
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SIZE = 16


def test_per_view_gaps_are_round_every_times_the_views_in_the_model():
    config = ExperimentConfig(n_initial=4, n_new=1, add_at_step=200, rounds=5, round_every=20)
    assert round_steps(config) == [200, 220, 240, 260, 280]
    grown = config.replace(round_growth="per-view")
    # After round r the model holds 4 + r views: the next round comes 20 x (4 + r) steps later.
    assert round_steps(grown) == [200, 200 + 100, 300 + 120, 420 + 140, 560 + 160]
    assert round_steps(grown.replace(n_new=2, rounds=3)) == [200, 200 + 20 * 6, 320 + 20 * 8]
    assert round_steps(grown.replace(rounds=1)) == [200]


def test_the_default_moves_no_fingerprint_and_the_rule_is_fingerprinted_only_when_used():
    config = ExperimentConfig(n_initial=4, n_new=1, rounds=3, round_every=20)
    assert "round_growth" not in config.fingerprinted()
    grown = config.replace(round_growth="per-view")
    assert grown.fingerprinted()["round_growth"] == "per-view"
    assert fingerprint(grown.fingerprinted()) != fingerprint(config.fingerprinted())
    # With one round there is no gap to grow: the rule changes nothing and splits no results.
    one = ExperimentConfig(rounds=1)
    assert fingerprint(one.replace(round_growth="per-view").fingerprinted()) == fingerprint(one.fingerprinted())


def test_a_schedule_whose_grown_rounds_pass_the_last_step_is_refused_naming_the_rule():
    tiny = PROTOCOL_PRESETS.choose("tiny")
    grown = dict(add_at_step=10, n_initial=3, n_new=1, rounds=3, round_every=10, round_growth="per-view")
    with pytest.raises(ValueError) as caught:  # refused when the config is made
        tiny.replace(steps=100, **grown)
    message = str(caught.value)
    assert message.startswith("--rounds 3: the last round would come at step 100 (--add-at-step 10, then 2 gaps")
    assert "per view in the model" in message and "\n" not in message
    check_config(tiny.replace(steps=101, **grown))
    with pytest.raises(ValueError, match=r"^--round-growth 'square': ") as caught:
        tiny.replace(steps=101, **(grown | {"round_growth": "square"}))
    assert "fixed" in str(caught.value) and "per-view" in str(caught.value)


def test_a_run_adds_its_views_at_the_grown_steps(tmp_path_factory):
    folder = tmp_path_factory.mktemp("toy") / "data"
    generator = torch.Generator().manual_seed(0)
    for split, n in (("train", 8), ("test", 2), ("initial", 2)):
        cameras = Cameras.from_fov(sample_uniform_poses(n, generator), BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
        images = torch.rand(n, SIZE, SIZE, 3, generator=generator)
        write_blender_split(folder, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))
    config = PROTOCOL_PRESETS.choose("tiny").replace(
        steps=40, add_at_step=5, n_initial=2, n_new=1, rounds=3, round_every=3, round_growth="per-view", n_test=2
    )
    config = config.replace(resolution=SIZE, view_uncertainty=False, hemisphere_map=False, save_renders=0)
    result = protocol.run_trial(RunKey("scene", "uniform", 0), folder, config, tmp_path_factory.mktemp("runs"))
    assert [r["step"] for r in result["rounds"]] == [5, 5 + 3 * 3, 14 + 3 * 4]
    assert [r["views"] for r in result["rounds"]] == [3, 4, 5]


def test_study_passes_the_rule_on_and_names_it_in_its_command():
    spec = StudySpec(out="s", rounds=3, round_every=20, round_growth="per-view")
    command = spec.command()
    assert command[command.index("--round-growth") + 1] == "per-view"
    assert "--round-growth" not in StudySpec(out="s", rounds=3).command()
