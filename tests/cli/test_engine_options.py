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
    # each cell named by the settings' nested names, as records name them
    assert seen[0].engines == (
        "cpu+field.hidden_dim=48+optimiser.batch_size=64",
        "nerfacto-cpu+field.hidden_dim=48+optimiser.batch_size=64",
    )


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


def study_engines(monkeypatch, tmp_path, engines: list[str]) -> tuple[str, ...]:
    """The cells `nerfaug study --engines ENGINES` would run (nothing runs)."""
    import nerfaug.cli.study_work as study_work

    seen = []
    monkeypatch.setattr(study_work, "run", lambda spec, *args, **kwargs: seen.append(spec) or {})
    monkeypatch.setattr(study_work, "record_table", lambda *args: {"runs": []})
    monkeypatch.setattr(study_work.study_page, "write_study", lambda *args: [])
    main(["study", "--out", str(tmp_path / "study"), "--engines", *engines, "--preset", "tiny"])
    return seen[0].engines


def test_a_study_cell_is_named_by_its_settings_nested_names(monkeypatch, tmp_path):
    # the value as the engine holds it (5e-3 is 0.005), the settings in the engine's order, hyphens read as on
    # the command line; the same engine twice is one cell
    cells = study_engines(
        monkeypatch,
        tmp_path,
        ["cpu+optimiser.lr=5e-3+field.hidden-dim=48", "cpu+field.hidden_dim=48+optimiser.lr=0.005", "test"],
    )
    assert cells == ("cpu+field.hidden_dim=48+optimiser.lr=0.005", "test")


def test_an_earlier_records_flat_cell_name_is_refused_with_the_nested_name_it_means(monkeypatch, tmp_path, capsys):
    with pytest.raises(SystemExit) as refused:
        study_engines(monkeypatch, tmp_path, ["cpu+lr=0.005"])
    assert refused.value.code == 2
    message = capsys.readouterr().err.strip()
    assert "\n" not in message and "--engines cpu+lr=0.005" in message and "cpu+optimiser.lr=0.005" in message
    assert not (tmp_path / "study").exists()


def test_a_nested_name_that_is_no_setting_is_refused_naming_it(monkeypatch, tmp_path, capsys):
    with pytest.raises(SystemExit) as refused:
        study_engines(monkeypatch, tmp_path, ["cpu+optimiser.rate=0.005"])
    assert refused.value.code == 2
    message = capsys.readouterr().err.strip()
    assert "\n" not in message and "'optimiser.rate' is no engine setting" in message


@pytest.mark.parametrize(
    "flat",
    [
        "nerfacto-cpu+background_mode=last_sample+hidden_dim=48",
        "paper+hidden_dim=32+proposal_samples=64,32+random_background=true",
        "nerfacto-cpu+encoding=kplanes+hidden_dim=48+sampler=occupancy+transmittance_eps=0.001",
        "cpu",
    ],
)
def test_a_cell_name_reads_back_as_its_engine_and_fingerprints_as_the_flat_name_did(flat):
    from nerfaug.nerf.engine import Engine

    engine = Engine.read(flat)
    cell = engine.cell_name()
    assert Engine.read(cell) == engine and Engine.read(cell).cell_name() == cell
    assert all("." in part.partition("=")[0] for part in cell.split("+")[1:])
    assert ExperimentConfig(engine=cell).fingerprinted() == ExperimentConfig(engine=flat).fingerprinted()
