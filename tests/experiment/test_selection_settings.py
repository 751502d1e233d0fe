"""Selection settings in sweeps: in the fingerprint (with the engine's whole config and the
dataset's identity), in each run's config.json, refused when changed, and on the command line."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views
from nerfaug.data.blender import write_blender_split
from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.fingerprints import VERSION_1
from nerfaug.experiment.protocol import builtin_dataset_digest
from nerfaug.experiment.store import IncompatibleResults, RunKey, fingerprint
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses, sample_uniform_poses
from nerfaug.selection import SelectionConfig


def test_every_selection_setting_and_the_whole_engine_config_are_fingerprinted(monkeypatch):
    from nerfaug.nerf import config as nerf_config

    config = PROTOCOL_PRESETS.choose("tiny")
    record = config.fingerprinted()
    # Every setting of fingerprint version 1 at every value; one added since, once it differs from
    # its default (tests/experiment/test_fingerprint_rule.py).
    for field in dataclasses.fields(SelectionConfig):
        assert f"selection.{field.name}" in record or f"selection.{field.name}" not in VERSION_1
    for name in nerf_config.FLAT_NAMES:  # every engine setting, by its flat name
        assert f"engine.{name}" in record or f"engine.{name}" not in VERSION_1
    assert {k for k in VERSION_1 if k.startswith(("selection.", "engine."))} <= record.keys()
    assert json.loads(json.dumps(record)) == record  # compares equal once read back from sweep.json

    changed = config.replace(selection=SelectionConfig(entropy_resolution=32)).fingerprinted()
    assert fingerprint(changed) != fingerprint(record)
    assert [k for k in record if record[k] != changed[k]] == ["selection.entropy_resolution"]

    # A changed engine default (not just the preset's name) changes the fingerprint.
    patched = nerf_config.PRESETS["test"].with_settings(field_lr=0.123)
    monkeypatch.setitem(nerf_config.PRESETS, "test", patched)
    engine_changed = config.replace(engine="test").fingerprinted()  # the engine is resolved where it is named
    assert [k for k in record if record[k] != engine_changed[k]] == ["engine.field_lr"]
    # So does a per-scene override.
    overrides = config.replace(field_lr={"lego": 0.5}).fingerprinted()
    assert overrides["field_lr"] != record["field_lr"]


def test_builtin_dataset_identity_follows_what_is_rendered():
    config = PROTOCOL_PRESETS.choose("tiny")
    digest = builtin_dataset_digest("lego", config)
    assert digest == builtin_dataset_digest("lego", config)
    assert digest != builtin_dataset_digest("chair", config)
    assert digest != builtin_dataset_digest("lego", config.replace(render_samples=8))
    assert digest != builtin_dataset_digest("lego", config.replace(seed=3))


@pytest.fixture(scope="module")
def toy_dataset(tmp_path_factory) -> Path:
    """A Blender-format dataset of random images at the tiny preset's size (no rendering)."""
    root = tmp_path_factory.mktemp("toy")
    generator = torch.Generator().manual_seed(0)

    def views(poses, prefix):
        cams = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 24, 24)
        images = torch.rand(len(cams), 24, 24, 3, generator=generator)
        return Views(cams, images, [f"{prefix}_{i}" for i in range(len(cams))])

    write_blender_split(root, "train", views(sample_uniform_poses(12, generator), "r"))
    write_blender_split(root, "initial", views(half_hemisphere_poses(3), "i"))
    write_blender_split(root, "test", views(sample_uniform_poses(3, generator), "t"))
    return root


def test_changed_selection_setting_is_refused_by_name(toy_dataset, tmp_path):
    from nerfaug.experiment.sweep import run_sweep

    config = PROTOCOL_PRESETS.choose("tiny").replace(scenes=(str(toy_dataset),), methods=("ours",), trials=1)
    outcome = run_sweep(config, tmp_path, progress=False)
    assert not outcome.failed and len(outcome.results) == 1
    saved = json.loads((RunKey(toy_dataset.name, "ours", 0).folder(tmp_path) / "config.json").read_text())
    assert saved["experiment"]["selection"] == SelectionConfig().to_dict()
    assert saved["selection"] == SelectionConfig().to_dict()  # what the method ran with
    assert saved["method"] == {"estimator": "combined", "selector": "sampling", "settings": {}}

    changed = config.replace(selection=SelectionConfig(entropy_resolution=32))
    with pytest.raises(IncompatibleResults, match=r"selection\.entropy_resolution: 40 -> 32"):
        run_sweep(changed, tmp_path, progress=False)
    # Growing the sweep with another method is fine, and records that method's own settings.
    grown = run_sweep(config.replace(methods=("ours", "ours-authors")), tmp_path, progress=False)
    assert not grown.failed and grown.skipped == 1
    saved = json.loads((RunKey(toy_dataset.name, "ours-authors", 0).folder(tmp_path) / "config.json").read_text())
    assert saved["selection"] == SelectionConfig().authors_variant().to_dict()


def test_run_and_propose_help_show_the_selection_options(capsys):
    from nerfaug.cli import main

    for command in ("run", "propose"):
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        for option in ("--selection.entropy-resolution", "--selection.sharpness", "--selection.min-polar"):
            assert option in text, (command, option)
        assert "width in pixels of each candidate's render" in " ".join(text.split())  # the attribute's docstring


def test_a_selection_is_recorded_as_the_options_that_give_it_again():
    import tyro

    given = SelectionConfig(entropy_resolution=20, sharpness=0.3)
    assert given.changes() == {"entropy_resolution": 20, "sharpness": 0.3}
    flags = given.flags()
    assert flags == ["--selection.entropy-resolution", "20", "--selection.sharpness", "0.3"]
    assert tyro.cli(SelectionConfig, args=[w.replace("--selection.", "--") for w in flags]) == given
