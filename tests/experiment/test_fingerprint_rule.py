"""A setting added with its default moves no recorded fingerprint; set otherwise, it does.

The tests add settings as a later version would: one more field of `ExperimentConfig` and of
`SelectionConfig` (subclasses), and one more engine setting (a flat name whose value every
`NerfConfig` has), then run on every committed study table the very check that guards the recorded
fingerprints (tests/experiment/test_recorded_fingerprints.py)."""

import dataclasses
import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import pytest

from nerfaug.experiment import fingerprints
from nerfaug.experiment.config import NOT_FINGERPRINTED, ExperimentConfig
from nerfaug.experiment.fingerprints import VERSION_1, engine_record
from nerfaug.experiment.store import fingerprint
from nerfaug.nerf import config as nerf_config
from nerfaug.nerf.config import NerfConfig, RendererConfig
from nerfaug.selection.config import SelectionConfig

_spec = importlib.util.spec_from_file_location("recorded", Path(__file__).with_name("test_recorded_fingerprints.py"))
recorded = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(recorded)


@dataclass
class LaterSelection(SelectionConfig):
    """The selection options with one setting added."""

    dither_views: bool = False


@dataclass
class LaterExperiment(ExperimentConfig):
    """The protocol with one setting added."""

    warm_start: int = 0


def add_engine_setting(monkeypatch, value) -> None:
    """One more engine setting, "ray_jitter" (renderer.ray_jitter), `value` in every `NerfConfig`."""
    monkeypatch.setitem(nerf_config.FLAT_NAMES, "ray_jitter", ("renderer", "ray_jitter"))
    monkeypatch.setattr(RendererConfig, "ray_jitter", value, raising=False)


def add_settings(monkeypatch) -> None:
    """A protocol, a selection and an engine setting added with their defaults, for the committed check."""
    add_engine_setting(monkeypatch, False)
    monkeypatch.setattr(recorded, "SelectionConfig", LaterSelection)
    monkeypatch.setattr(recorded, "ExperimentConfig", LaterExperiment)


@pytest.mark.parametrize("name", recorded.TABLES)
def test_settings_added_with_their_defaults_move_no_committed_fingerprint(monkeypatch, name):
    add_settings(monkeypatch)
    plan = json.loads((recorded.RESULTS / name).read_text())["plan"]
    config = recorded.plan_config(plan, "nerfacto-cpu", None)
    # The committed check builds its configs with the added settings ...
    assert isinstance(config, LaterExperiment) and isinstance(config.selection, LaterSelection)
    assert config.engine.config.flat()["ray_jitter"] is False
    # ... which the record holds once they differ from their defaults,
    changed = config.replace(warm_start=2, selection=dataclasses.replace(config.selection, dither_views=True))
    assert {"warm_start": 2, "selection.dither_views": True}.items() <= changed.fingerprinted().items()
    # and at their defaults every run of the table keeps its fingerprint.
    recorded.test_every_committed_run_keeps_its_fingerprint(name)


def test_a_later_setting_set_otherwise_changes_the_fingerprint(monkeypatch):
    add_engine_setting(monkeypatch, False)
    base = LaterExperiment(device="cpu")
    record = base.fingerprinted()
    assert not {"warm_start", "selection.dither_views", "engine.ray_jitter"} & record.keys()
    for changed, name in (
        (base.replace(warm_start=3), "warm_start"),
        (base.replace(selection=LaterSelection(dither_views=True)), "selection.dither_views"),
    ):
        other = changed.fingerprinted()
        assert [k for k in {*record, *other} if record.get(k) != other.get(k)] == [name]
        assert fingerprint(other) != fingerprint(record)
    # An engine that sets the added engine setting otherwise is hashed with it.
    engine = NerfConfig.preset("cpu")
    assert "engine.ray_jitter" not in engine_record(engine)
    object.__setattr__(engine.renderer, "ray_jitter", True)  # a fresh copy: `preset` builds one per call
    assert engine_record(engine)["engine.ray_jitter"] is True
    assert "engine.ray_jitter" not in engine_record(NerfConfig.preset("cpu"))


def test_a_default_declared_not_neutral_is_hashed(monkeypatch):
    """A setting whose default changes the numbers (a kernel on by default) declares its neutral
    value, and every fingerprint moves: results made before it are not mixed with new ones."""
    add_engine_setting(monkeypatch, True)
    config = LaterExperiment(device="cpu")
    before = config.fingerprinted()
    assert "engine.ray_jitter" not in before and "warm_start" not in before
    monkeypatch.setattr(fingerprints, "NEUTRAL", MappingProxyType({"engine.ray_jitter": False, "warm_start": 1}))
    after = config.fingerprinted()
    assert after == {**before, "engine.ray_jitter": True, "warm_start": 0}
    assert fingerprint(after) != fingerprint(before)


def test_every_version_1_setting_is_hashed_at_every_value(monkeypatch):
    """The settings every recorded run hashed stay in the record at their defaults (a misspelt
    name in `VERSION_1` would drop one and move every recorded fingerprint)."""
    from nerfaug.experiment import config as experiment_config

    record = ExperimentConfig(device="cpu").fingerprinted()
    assert VERSION_1 <= record.keys()
    assert record.keys() - VERSION_1 == set()  # compile, layouts, engine_version: at their neutral values
    # A batch's size changes no number: it sets no run apart.
    assert ExperimentConfig(device="cpu", batch=4).fingerprinted() == record
    monkeypatch.setattr(experiment_config.ExperimentConfig, "engine_version", lambda self: "2")  # a new arithmetic
    assert {"compile", "layouts", "engine_version"} <= ExperimentConfig(
        device="cpu", compile="inductor", layouts=2
    ).fingerprinted().keys()


# A value other than the default for each protocol field that is fingerprinted as itself.
OTHER_VALUES = {"engine": "test", "field_lr": {}, "compile": "inductor"}


def test_every_protocol_field_is_fingerprinted_unless_declared_not_to_be():
    base = ExperimentConfig(device="cpu")
    names = {f.name for f in dataclasses.fields(ExperimentConfig)}
    assert NOT_FINGERPRINTED <= names
    record = base.fingerprinted()
    for name in sorted(names - NOT_FINGERPRINTED - {"device", "batch", "selection", "round_every", "round_growth"}):
        value = OTHER_VALUES[name] if name in OTHER_VALUES else getattr(base, name) + 1
        changed = base.replace(**{name: value}).fingerprinted()
        assert fingerprint(changed) != fingerprint(record), name
    # The spacing of rounds counts where there is more than one round; with one it changes nothing.
    assert base.replace(round_every=50).fingerprinted() == record
    rounds = base.replace(rounds=3)
    assert fingerprint(rounds.replace(round_every=50).fingerprinted()) != fingerprint(rounds.fingerprinted())
    assert base.replace(round_growth="per-view").fingerprinted() == record  # so does their growth
    tight = rounds.replace(round_every=20)  # grown gaps of 100 steps a view would pass the last step
    assert fingerprint(tight.replace(round_growth="per-view").fingerprinted()) != fingerprint(tight.fingerprinted())
    # What a run saves beside its numbers, and which runs a sweep makes, are not.
    for name, value in (("hemisphere_map", False), ("view_uncertainty", False), ("save_renders", 0), ("trials", 9)):
        assert name in NOT_FINGERPRINTED
        assert base.replace(**{name: value}).fingerprinted() == record, name


# Fingerprints of the study preset's protocol (engine "cpu": no hash grid, so no engine version on
# any machine), computed before the spacing of rounds was declared unused with one round in
# `fingerprints.UNUSED_WHEN` (it was a special case in `ExperimentConfig.fingerprinted`).
PINNED = [
    ({}, "8c7a5d141f01bcf4"),
    ({"round_every": 50}, "8c7a5d141f01bcf4"),
    ({"round_every": 50, "round_growth": "per-view"}, "8c7a5d141f01bcf4"),
    ({"rounds": 8, "n_initial": 4, "n_new": 1, "round_every": 100}, "2b5849cdf84b19f7"),
    ({"rounds": 8, "n_initial": 4, "n_new": 1, "round_every": 50}, "39edde32b700570e"),
    ({"rounds": 3, "n_new": 2, "round_every": 20, "round_growth": "per-view"}, "04d48b78822d718d"),
]


@pytest.mark.parametrize(("changes", "expected"), PINNED)
def test_the_declared_unused_settings_move_no_fingerprint(changes, expected):
    from nerfaug.experiment.config import STUDY_PRESETS

    config = STUDY_PRESETS.choose("study", device="cpu", **changes)
    assert config.engine_version() is None
    assert fingerprint(config.fingerprinted()) == expected


def test_with_one_round_the_spacing_of_rounds_is_hashed_by_the_declared_rule(monkeypatch):
    one = ExperimentConfig(device="cpu")
    spaced = one.replace(round_every=50, round_growth="per-view")
    assert spaced.fingerprinted() == one.fingerprinted()
    # Without the declaration the same settings would split runs of one round.
    monkeypatch.setattr(fingerprints, "UNUSED_WHEN", ())
    record = spaced.fingerprinted()
    assert {"round_every": 50, "round_growth": "per-view"}.items() <= record.items()
    assert fingerprint(record) != fingerprint(one.fingerprinted())
    # Declared for another value of the condition, it leaves runs in rounds unsplit by their spacing.
    monkeypatch.setattr(fingerprints, "UNUSED_WHEN", (("rounds", 3, ("round_every",)),))
    three = ExperimentConfig(device="cpu", rounds=3, n_new=1, round_every=20)
    assert "round_every" not in three.fingerprinted()
    assert three.replace(round_every=30).fingerprinted() == three.fingerprinted()
