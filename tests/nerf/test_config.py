"""`NerfConfig` nested by component: one flat name per setting (the names fingerprints, variants
and files written before the nesting use), both forms read back, the groups' checks, and the
settings as command options (`--engine.field.hidden-dim 32`) parsed by tyro."""

import json
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Annotated

import pytest
import tyro

from nerfaug.nerf.config import (
    FLAT_NAMES,
    PRESETS,
    NerfConfig,
    ProposalConfig,
    SceneConfig,
)
from nerfaug.nerf.engine import Engine
from nerfaug.nerf.engine_form import EngineSettings
from nerfaug.schema import RequestError

OLD_SESSION = Path(__file__).parents[1] / "capture" / "data" / "session_v1.json"


def leaves(config):
    """Every setting an engine object holds, by walking its dataclasses (not `nerf.names`)."""
    for f in fields(config):
        value = getattr(config, f.name)
        yield from leaves(value) if is_dataclass(value) else [value]


def test_every_setting_has_one_flat_name_and_the_flat_view_holds_each_once():
    assert len(set(FLAT_NAMES)) == len(set(FLAT_NAMES.values())) == 47  # those of the flat config it replaced
    for name, config in PRESETS.items():  # an engine holds its parts' settings, each once, and no other part's
        choosers = 2  # the encoding's and the sampler's part: one object each, one name each
        assert len(config.flat()) == len(list(leaves(config))) + choosers, name
        parts = {"hash_", "plane_"} - {"hash_" if config.flat()["encoding"] == "hash" else "plane_"}
        parts |= {"occupancy_", "proposal_"} - {f"{config.flat()['sampler']}_"}
        assert not any(flat.startswith(tuple(parts)) for flat in config.flat()), name
    # Prefixed groups keep the names results were fingerprinted by.
    assert FLAT_NAMES["hash_levels"] == ("field", "hash", "levels")
    assert FLAT_NAMES["occupancy_warmup_steps"] == ("sampler", "occupancy", "warmup_steps")
    assert FLAT_NAMES["sampler"] == ("sampler", "kind")
    assert FLAT_NAMES["distortion_loss_mult"] == ("sampler", "proposal", "distortion_loss_mult")
    config = PRESETS["nerfacto-cpu"]
    assert config.flat()["hash_levels"] == config.field.encoding.levels == 6


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_both_forms_read_back_to_the_same_engine(name):
    config = PRESETS[name]
    as_json = json.loads(json.dumps(config.to_dict()))  # tuples become lists, as in session.json
    assert NerfConfig.from_dict(as_json) == config
    assert NerfConfig.from_dict(json.loads(json.dumps(config.flat()))) == config
    assert NerfConfig().with_settings(**config.flat()) == config


def test_the_flat_engine_of_a_session_written_before_the_nesting_reads():
    old = json.loads(OLD_SESSION.read_text())["engine"]
    assert "hash_levels" in old and "field" not in old
    assert NerfConfig.from_dict(old) == PRESETS["test"]


def test_an_unknown_setting_is_refused_by_name_in_either_form():
    with pytest.raises(ValueError, match="unknown engine setting 'hiden_dim'; did you mean 'hidden_dim'"):
        NerfConfig().with_settings(hiden_dim=3)
    with pytest.raises(ValueError, match=r"engine\.field: unknown setting 'hiden_dim'"):
        NerfConfig.from_dict({"field": {"hiden_dim": 3}})


def test_each_group_checks_its_settings_and_changes_are_checked_together():
    with pytest.raises(ValueError, match="near < far"):
        SceneConfig(near=3.0, far=2.0)
    with pytest.raises(ValueError, match="one entry per proposal network"):
        PRESETS["nerfacto-cpu"].with_settings(proposal_samples=(8,))
    # Changed together, the pair is consistent: no intermediate state is checked.
    both = PRESETS["nerfacto-cpu"].with_settings(proposal_samples=(8,), proposal_max_resolutions=(32,))
    assert both.sampler.kind == ProposalConfig(samples=(8,), hash_levels=3, max_resolutions=(32,), log2_table_size=12)
    with pytest.raises(ValueError, match="background_mode must be one of"):
        NerfConfig().with_settings(background_mode="grey")


def test_an_engine_records_the_settings_that_differ_by_their_nested_names_and_reads_back():
    settings = {"field": {"hidden_dim": 32}, "optimiser": {"lr": 0.01}, "sampler": {"proposal": {"samples": [64, 32]}}}
    engine = Engine.of("paper", settings)
    # lr is the paper's own: left out; JSON's lists read as the tuples a config holds
    assert engine.record() == {
        "preset": "paper",
        "field": {"hidden_dim": 32},
        "sampler": {"proposal": {"samples": [64, 32]}},
    }
    assert engine.config == PRESETS["paper"].with_settings(hidden_dim=32, proposal_samples=(64, 32))
    assert Engine.read(json.loads(json.dumps(engine.record()))) == engine
    assert engine.options() == "--engine paper --engine.field.hidden-dim 32 --engine.sampler.proposal.samples 64 32"
    # An earlier record's flat name reads as the same engine, and is the name its fingerprint hashed.
    assert Engine.read("paper+hidden_dim=32+proposal_samples=64,32") == engine
    assert engine.flat_name() == "paper+hidden_dim=32+proposal_samples=64,32"
    assert engine.with_settings({"field": {"hidden_dim": 64}}).record() == {
        "preset": "paper",
        "sampler": {"proposal": {"samples": [64, 32]}},
    }
    assert Engine.of("cpu", {"renderer": {"random_background": True}}).flat_name() == "cpu+random_background=true"
    with pytest.raises(ValueError, match="background_mode"):
        Engine.of("paper", {"renderer": {"background_mode": "grey"}})
    with pytest.raises(RequestError, match="field.hidden_dim 32.5: Input should be a valid integer"):
        Engine.of("paper", {"field": {"hidden_dim": 32.5}})  # refused here, not inside torch
    with pytest.raises(ValueError, match="engine.field: unknown setting 'hidden_dimm'"):
        Engine.read({"preset": "paper", "field": {"hidden_dimm": 32}})


@dataclass
class Command:
    engine: str = "nerfacto-cpu"
    engine_settings: Annotated[EngineSettings, tyro.conf.arg(name="engine")] = EngineSettings()


def test_engine_settings_are_command_options_beside_the_engine_in_any_order():
    args = [
        "--engine.field.hidden-dim", "32",
        "--engine", "paper",
        "--engine.sampler.proposal.samples", "64", "32",
        "--engine.renderer.random-background", "True",
    ]  # fmt: skip
    parsed = tyro.cli(Command, args=args)
    given = parsed.engine_settings.given()
    assert given == {
        "field": {"hidden_dim": 32},
        "sampler": {"proposal": {"samples": (64, 32)}},
        "renderer": {"random_background": True},
    }
    engine = Engine.of(parsed.engine, given)
    assert engine.flat_name() == "paper+hidden_dim=32+proposal_samples=64,32+random_background=true"
    assert tyro.cli(Command, args=[]).engine_settings.given() == {}


def test_engine_settings_help_names_each_option_with_its_docstring(capsys):
    with pytest.raises(SystemExit):
        tyro.cli(Command, args=["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--engine.field.hidden-dim INT" in text and "density MLP width" in text
    assert "--engine.sampler.occupancy.warmup-steps INT" in text
    assert "(default: the engine's)" in text and "None" not in text


def test_a_wrong_type_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        tyro.cli(Command, args=["--engine.field.hidden-dim", "wide"])
    assert "hidden-dim" in capsys.readouterr().err
