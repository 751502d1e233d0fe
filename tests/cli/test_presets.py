"""`nerfaug run`'s options start from its preset: an option given on the command line applies even
when its value is the dataclass default, and one not given keeps the preset's value."""

import pytest

from nerfaug.cli import main
from nerfaug.experiment import config as experiment_config
from nerfaug.experiment.sweep import SweepOutcome
from nerfaug.selection.methods import SelectionConfig

DEFAULT = SelectionConfig()


@pytest.fixture
def planned(monkeypatch, tmp_path):
    """Run `nerfaug run --preset tiny ARGS` without running anything: the configs it would sweep.
    The tiny preset is given selection settings of its own (none of the real presets has any)."""
    import nerfaug.experiment.sweep as sweep

    configs = []

    def run_sweep(config, out, **_):
        configs.append(config)
        return SweepOutcome([], {})

    monkeypatch.setattr(sweep, "run_sweep", run_sweep)
    preset_selection = SelectionConfig(temperature=0.5, entropy_resolution=30, sharpness=0.2)
    tiny = experiment_config.PROTOCOL_PRESETS.choose("tiny", selection=preset_selection)
    monkeypatch.setitem(experiment_config.PROTOCOL_PRESETS, "tiny", tiny)

    def plan(*args: str):
        main(["run", "--out", str(tmp_path / "out"), "--preset", "tiny", "--no-report", *args])
        return configs[-1]

    return plan


def test_options_not_given_keep_the_presets_values(planned):
    config = planned()
    assert (config.selection.temperature, config.selection.entropy_resolution, config.selection.sharpness) == (
        0.5,
        30,
        0.2,
    )
    assert config.trials == 2 and config.steps == 60  # the tiny preset's


def test_a_selection_option_given_at_its_default_replaces_the_presets_value(planned):
    assert DEFAULT.temperature == 1.0 and DEFAULT.entropy_resolution == 40 and DEFAULT.sharpness is None
    config = planned("--selection.temperature", "1.0", "--selection.entropy_resolution=40")
    assert (config.selection.temperature, config.selection.entropy_resolution) == (1.0, 40)
    assert config.selection.sharpness == 0.2  # not given: the preset's
    assert planned("--selection.sharpness", "None").selection.sharpness is None


def test_a_protocol_option_given_at_the_dataclass_default_replaces_the_presets_value(planned):
    default = experiment_config.ExperimentConfig()
    config = planned("--trials", str(default.trials), "--steps", str(default.steps), "--seed", "0")
    assert (config.trials, config.steps, config.seed) == (default.trials, default.steps, 0)
    assert config.n_test == 3  # not given: the preset's


def test_the_options_start_from_the_preset_the_command_line_names(monkeypatch, tmp_path):
    import nerfaug.experiment.sweep as sweep

    configs = []
    monkeypatch.setattr(sweep, "run_sweep", lambda config, out, **_: configs.append(config) or SweepOutcome([], {}))
    main(["run", "--out", str(tmp_path / "paper"), "--no-report", "--steps", "5000", "--preset=paper"])
    paper = experiment_config.PROTOCOL_PRESETS["paper"]
    assert (configs[-1].steps, configs[-1].trials, configs[-1].resolution) == (5000, paper.trials, paper.resolution)


def test_an_unknown_preset_is_refused_by_the_parser_with_the_known_names(capsys):
    with pytest.raises(SystemExit) as refused:
        main(["run", "--out", "nowhere", "--preset", "fast"])
    assert refused.value.code == 2
    error = capsys.readouterr().err
    assert "fast" in error and "quick" in error and "paper" in error


def test_run_prints_its_size_and_an_estimate_before_it_starts(planned, capsys):
    planned("--trials", "3", "--workers", "1", "--device", "cpu")
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("nerfaug run: 6 runs (1 scene x 2 methods x 3 trials), 24x24 pixels, 60 steps each")
    assert "6 to run: about " in first and "(cpu, 1 run at a time" in first and "An estimate" in first
