"""An experiment's and a study's settings are checked once, when they are made: each setting by the
bounds in its annotation (strict types), the rules between them by the config's validator; a
refusal is one line naming the option as the command line spells it."""

from __future__ import annotations

import dataclasses
import math

import pytest

from nerfaug.cli import main
from nerfaug.cli.study import Study
from nerfaug.experiment.config import PROTOCOL_PRESETS, STUDY_PRESETS, ExperimentConfig
from nerfaug.experiment.study_spec import StudySpec
from nerfaug.nerf.config import NerfConfig
from nerfaug.schema import RequestError
from nerfaug.selection.config import SelectionConfig

# Every whole-number setting of the protocol, with the smallest value it takes.
WHOLE_NUMBERS = {
    "trials": 1,
    "seed": 0,
    "resolution": 1,
    "steps": 1,
    "add_at_step": 0,
    "n_new": 1,
    "n_initial": 1,
    "rounds": 1,
    "round_every": 1,
    "pool": 1,
    "n_test": 1,
    "layouts": 1,
    "render_samples": 1,
    "threads_per_run": 1,
    "save_renders": 0,
    "batch": 0,
}


def test_every_whole_number_setting_is_listed():
    defaults = ExperimentConfig()
    whole = {f.name for f in dataclasses.fields(defaults) if type(getattr(defaults, f.name)) is int}  # not bools
    assert whole == set(WHOLE_NUMBERS)


@pytest.mark.parametrize("name", sorted(WHOLE_NUMBERS))
@pytest.mark.parametrize("value", [32.0, "32", True, None])
def test_a_whole_number_setting_refuses_any_other_type_naming_its_option(name, value):
    with pytest.raises(RequestError) as caught:
        ExperimentConfig(**{name: value})
    option = "--" + name.replace("_", "-")
    assert str(caught.value) == f"{option} {value!r}: Input should be a valid integer"


@pytest.mark.parametrize("name", sorted(WHOLE_NUMBERS))
def test_a_whole_number_setting_refuses_one_below_its_bound(name):
    low = WHOLE_NUMBERS[name]
    with pytest.raises(RequestError, match=f"^--{name.replace('_', '-')} {low - 1}: must be >= {low}$"):
        ExperimentConfig(**{name: low - 1})


@pytest.mark.parametrize("value", [math.nan, math.inf, 0.0, -0.002, "0.002"])
def test_a_scenes_field_learning_rate_is_a_finite_positive_number(value):
    with pytest.raises(RequestError, match=r"^--field-lr\.chair "):
        ExperimentConfig(field_lr={"chair": value})
    assert ExperimentConfig(field_lr={"chair": 1}).field_lr == {"chair": 1}  # a whole number is a number


@pytest.mark.parametrize(
    ("changes", "refusal"),
    [
        ({"methods": ()}, "--methods ():"),
        ({"scenes": ()}, "--scenes ():"),
        ({"methods": ("ours", "ours")}, "--methods ('ours', 'ours'): a method is listed twice"),
        ({"engine": "nope"}, "--engine 'nope': unknown engine preset 'nope'"),
        ({"engine": "cpu+hidden_dim=0"}, "--engine 'cpu+hidden_dim=0':"),
        ({"steps": 200}, "--steps 200: must be greater than the step at which views are added (200)"),
        ({"rounds": 30}, "--rounds 30: the last round would come at step 3100"),
        ({"pool": 5}, "--pool 5: the pool must hold the 6 views to add"),
        ({"device": "tpu"}, "--device 'tpu':"),
        ({"selection": SelectionConfig(sharpness=2.0)}, "--selection.sharpness 2.0: must be <= 1"),
        ({"colour": 1}, None),  # not a setting: Python's own TypeError
    ],
)
def test_a_bad_config_is_refused_when_it_is_made_in_one_line(changes, refusal):
    with pytest.raises(TypeError if refusal is None else ValueError) as caught:
        ExperimentConfig(**changes)
    if refusal is not None:
        assert str(caught.value).startswith(refusal) and "\n" not in str(caught.value)


def test_replace_checks_the_config_it_makes():
    config = PROTOCOL_PRESETS.choose("tiny")
    with pytest.raises(ValueError, match="^--steps 20: must be greater than the step at which views are added"):
        config.replace(steps=20)
    with pytest.raises(RequestError, match="^--n-new 2.0: "):
        config.replace(n_new=2.0)
    assert config.replace(steps=21).steps == 21


def test_every_preset_is_a_valid_config():
    for presets in (PROTOCOL_PRESETS, STUDY_PRESETS):
        for name in presets:
            config = presets.choose(name)
            config.check()  # raises if not
            assert dataclasses.replace(config) == config


def test_a_study_spec_refuses_its_options_by_name():
    for changes, refusal in [
        ({"trials": 0}, "--trials 0: must be >= 1"),
        ({"steps": 2000.0}, "--steps 2000.0: Input should be a valid integer"),
        ({"add_at_step": -1}, "--add-at-step -1: must be >= 0"),
        ({"n_initial": "4"}, "--n-initial '4': Input should be a valid integer"),
        ({"batch": -1}, "--batch -1: must be >= 0"),
        ({"engines": ()}, "--engines ():"),
    ]:
        for kind in (StudySpec, Study):
            with pytest.raises(RequestError) as caught:
                kind(**changes)
            assert str(caught.value).startswith(refusal)
    assert StudySpec(trials=None, n_initial=None).trials is None  # decided when the study is planned


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["run", "--preset", "tiny", "--trials", "0"], "nerfaug: --trials 0: must be >= 1\n"),
        (["run", "--preset", "tiny", "--steps", "20"], "nerfaug: --steps 20: must be greater than the step"),
        (["study", "--trials", "0"], "nerfaug: --trials 0: must be >= 1\n"),  # not tyro's box
        (["study", "--rounds", "2", "--round-every", "5000"], "nerfaug: --rounds 2: the last round would come at"),
        (["run", "--selection.sharpness", "2"], "nerfaug: --selection.sharpness 2.0: must be <= 1\n"),
    ],
)
def test_the_commands_refuse_a_setting_in_one_line_before_anything_is_written(argv, says, tmp_path, capsys):
    with pytest.raises(SystemExit) as done:
        main([*argv, "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert done.value.code == 2 and err.startswith(says) and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", [32.0, "32", True])
def test_an_engine_whole_number_refuses_another_type(value):
    with pytest.raises(RequestError) as caught:
        NerfConfig.preset("cpu").with_settings(hidden_dim=value)
    assert str(caught.value) == f"field.hidden_dim {value!r}: Input should be a valid integer"
    assert NerfConfig.preset("cpu").with_settings(hidden_dim=32).field.hidden_dim == 32
    assert NerfConfig.preset("cpu").with_settings(near=1).scene.near == 1  # a whole number is a number
