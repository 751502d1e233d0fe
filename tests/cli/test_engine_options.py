"""Any engine setting is an option of every command that trains, with one syntax:
`--engine NAME --engine.GROUP.SETTING VALUE`. The command's engine is the preset with those settings
changed, by their nested names, which sessions and runs record ({"preset": "paper", "field":
{"hidden_dim": 48}}) and fingerprint."""

import json

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession
from nerfaug.cli import main
from nerfaug.data import Views, write_blender_split
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.sweep import SweepOutcome
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses
from nerfaug.nerf.config import NerfConfig

OVERRIDE = ["--engine.field.hidden-dim", "48", "--engine.optimiser.batch-size", "64"]


@pytest.fixture
def swept(monkeypatch):
    """The configs `nerfaug run` would sweep, without running anything."""
    import nerfaug.experiment.sweep as sweep

    configs = []
    monkeypatch.setattr(sweep, "run_sweep", lambda config, out, **_: configs.append(config) or SweepOutcome([], {}))
    return configs


def test_run_takes_engine_settings_over_its_engine(swept, tmp_path):
    main(["run", "--out", str(tmp_path / "out"), "--preset", "tiny", "--no-report", "--engine", "cpu", *OVERRIDE])
    (config,) = swept
    assert config.to_record()["engine"] == {
        "preset": "cpu",
        "field": {"hidden_dim": 48},
        "optimiser": {"batch_size": 64},
    }
    engine = config.engine_config("lego")
    assert (engine.field.hidden_dim, engine.optimiser.batch_size) == (48, 64)
    record = config.fingerprinted()
    assert record["engine.hidden_dim"] == 48 and record["engine.plane_features"] == 8  # the rest: cpu's
    # the fingerprint hashes the engine by the name earlier runs recorded it under: none moves
    assert record["engine"] == "cpu+hidden_dim=48+batch_size=64"


def test_the_engine_option_takes_a_preset_and_an_earlier_records_name_reads(swept, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["run", "--out", str(tmp_path / "out"), "--preset", "tiny", "--no-report", "--engine", "cpu+lr=0.005"])
    assert "--engine.optimiser.lr" in capsys.readouterr().err
    assert ExperimentConfig(engine="cpu+lr=0.005").to_record()["engine"] == {
        "preset": "cpu",
        "optimiser": {"lr": 0.005},
    }


def test_study_applies_engine_settings_to_every_engine(monkeypatch, tmp_path):
    import nerfaug.cli.study_work as study_work

    seen = []
    monkeypatch.setattr(study_work, "run", lambda spec, *args, **kwargs: seen.append(spec) or {})
    monkeypatch.setattr(study_work, "record_table", lambda *args: {"runs": []})
    monkeypatch.setattr(study_work.study_page, "write_study", lambda *args: [])
    main(["study", "--out", str(tmp_path / "study"), "--engines", "cpu", "nerfacto-cpu", "--preset", "tiny", *OVERRIDE])
    assert seen[0].engines == ("cpu+hidden_dim=48+batch_size=64", "nerfacto-cpu+hidden_dim=48+batch_size=64")


def test_train_records_the_variant_trains_with_its_settings_and_logs(tmp_path):
    generator = torch.Generator().manual_seed(0)
    poses, images = sample_uniform_poses(4, generator), torch.rand(4, 8, 8, 3, generator=generator)
    data, run = tmp_path / "data", tmp_path / "run"
    cameras, names = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8), [f"./x/r_{i}" for i in range(4)]
    write_blender_split(data, "train", Views(cameras, images, names))
    args = ["--steps", "20", "--device", "cpu", "--engine", "test", "--logger", "tensorboard", *OVERRIDE]
    main(["train", str(data), "--out", str(run), *args])
    state = json.loads((run / "session.json").read_text())
    assert state["engine"] == {"preset": "test", "field": {"hidden_dim": 48}, "optimiser": {"batch_size": 64}}
    assert NerfConfig.from_dict(state["engine_config"]) == NerfConfig.preset("test", hidden_dim=48, batch_size=64)
    session = CaptureSession.open(run)
    assert session.trainer.model.field.density_mlp[0].out_features == 48  # the field built is 48 wide
    assert len(list((run / "tensorboard").glob("events.out.tfevents.*"))) == 1  # --logger tensorboard


def test_a_bad_engine_setting_is_one_line_naming_it(capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["run", "--out", str(tmp_path / "o"), "--preset", "tiny", "--engine.renderer.background-mode", "grey"])
    assert "background-mode" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["serve", "--root", str(tmp_path), "--engine.field.hidden-dim", "0"])
    err = capsys.readouterr().err
    assert err == "nerfaug: --engine.field.hidden-dim 0: must be >= 1\n"


@pytest.mark.parametrize(
    "setting",
    [
        ("--engine.field.hidden-dim", "0"),  # a width of 0 would build a field that cannot learn
        ("--engine.optimiser.lr", "-0.01"),
        ("--engine.field.sh-levels", "5"),  # the direction encoding has 4 levels
        ("--engine.sampler.proposal.interlevel-loss-mult", "-0.5"),
    ],
)
def test_train_refuses_a_setting_out_of_its_bounds_before_reading_anything(capsys, tmp_path, setting):
    with pytest.raises(SystemExit):
        main(["train", str(tmp_path / "no-data"), "--out", str(tmp_path / "run"), "--engine", "paper", *setting])
    err = capsys.readouterr().err
    assert err.startswith(f"nerfaug: {setting[0]} {setting[1]}: must be ") and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_train_refuses_a_setting_of_a_part_its_engine_did_not_choose_in_one_line(capsys, tmp_path):
    setting = ["--engine.sampler.occupancy.ema-decay", "0.5"]  # paper samples with proposal networks
    with pytest.raises(SystemExit):
        main(["train", str(tmp_path / "no-data"), "--out", str(tmp_path / "run"), "--engine", "paper", *setting])
    err = capsys.readouterr().err
    assert err == (
        "nerfaug: --engine.sampler.occupancy.ema-decay 0.5: not used by this engine: its sampler.kind is "
        "'proposal' (this setting is read with 'occupancy')\n"
    )
    assert list(tmp_path.iterdir()) == []


def test_train_checks_every_session_setting_before_reading_the_data(capsys, tmp_path):
    with pytest.raises(SystemExit):
        main(["train", str(tmp_path / "no-data"), "--out", str(tmp_path / "run"), "--seed", "-1"])
    assert capsys.readouterr().err.strip() == "nerfaug: --seed -1: must be >= 0"


def test_serve_names_the_engines_its_settings_do_not_fit(capsys):
    from nerfaug.cli.serve import _check_engine_settings

    _check_engine_settings(
        {"field": {"planes": {"resolutions": (32,)}}}
    )  # the K-planes engines read it; the hash-grid ones do not
    err = capsys.readouterr().err
    assert err.startswith("warning: a session asking for the engine paper, nerfacto-cpu, nerfacto-cpu-last-sample ")
    assert "--engine.field.planes.resolutions 32: not used" in err and "cpu," not in err.replace("nerfacto-cpu,", "")


def test_a_setting_is_refused_as_the_option_on_run_and_study(capsys, tmp_path):
    for command in (["run", "--out", str(tmp_path / "o"), "--preset", "tiny"], ["study", "--out", str(tmp_path / "s")]):
        with pytest.raises(SystemExit):
            main([*command, "--engine.optimiser.batch-size", "0"])
        assert capsys.readouterr().err == "nerfaug: --engine.optimiser.batch-size 0: must be >= 1\n"
    assert list(tmp_path.iterdir()) == []
