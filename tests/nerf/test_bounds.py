"""Every engine setting's bounds: no float setting takes inf or nan, and a setting the engine does
not read is refused rather than naming a new engine that trains as the old one."""

import math

import pytest

from nerfaug.nerf import names
from nerfaug.nerf.config import FLAT_NAMES, PRESETS, HashGridConfig, NerfConfig, parse_variant
from nerfaug.nerf.engine import Engine
from nerfaug.schema import RequestError


def _float_settings() -> list[str]:
    """Flat names of the settings whose default is a float (read from the dataclasses' values, not
    from the bound types under test; a part's setting from the part's type)."""
    return [flat for flat, path in FLAT_NAMES.items() if isinstance(names.part_default(NerfConfig, path), float)]


def _engine_with(path: tuple[str, ...]) -> NerfConfig:
    """An engine that has the setting at `path`: the defaults (K-planes, occupancy grid) or the
    paper preset (hash grid, proposal networks)."""
    return NerfConfig() if not names.unused(NerfConfig(), path) else PRESETS["paper"]


def test_the_float_settings_are_all_found():
    assert {"field_lr", "far", "near", "box_half_size", "lr", "adam_eps"} <= set(_float_settings())
    assert len(_float_settings()) >= 15


@pytest.mark.parametrize("flat", _float_settings())
@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan])
def test_no_float_setting_takes_inf_or_nan(flat, value):
    with pytest.raises(ValueError) as refused:  # a RequestError, or a group's check of its settings together
        _engine_with(FLAT_NAMES[flat]).with_settings(**{flat: value})
    assert FLAT_NAMES[flat][-1] in str(refused.value) and "not used" not in str(refused.value)


def test_a_variant_name_with_an_infinite_learning_rate_is_refused():
    with pytest.raises(ValueError, match="field_lr inf: must be a finite number|finite"):
        parse_variant("test+field_lr=inf")


@pytest.mark.parametrize(
    "engine, setting",
    [
        ("test", {"hash_levels": 8}),
        ("cpu", {"hash_levels": 16}),
        ("nerfacto-cpu", {"plane_features": 4}),
        ("paper", {"occupancy_resolution": 32}),
        ("cpu", {"proposal_hidden_dim": 8}),
    ],
)
def test_a_setting_the_engine_does_not_read_is_refused(engine, setting):
    path = FLAT_NAMES[next(iter(setting))]
    nested = {path[0]: {path[1]: {path[2]: next(iter(setting.values()))}}}
    with pytest.raises(RequestError, match="not used by this engine: its (field.encoding|sampler.kind) is") as refused:
        Engine.of(engine, nested)
    assert refused.value.argument == ".".join(path)
    with pytest.raises(ValueError, match="not used by this engine"):
        parse_variant(f"{engine}+{next(iter(setting))}={next(iter(setting.values()))}")


def test_a_setting_read_once_its_part_is_chosen_is_taken():
    both = Engine.of("test", {"field": {"encoding": "hash", "hash": {"levels": 8}}})
    assert both.flat_name() == "test+encoding=hash+hash_levels=8"
    assert both.record() == {"preset": "test", "field": {"encoding": "hash", "hash": {"levels": 8}}}
    assert NerfConfig.preset("test+encoding=hash+hash_levels=8").field.encoding == HashGridConfig(levels=8)


def test_an_engine_cannot_hold_a_setting_of_a_part_it_did_not_choose():
    config = NerfConfig.preset("cpu")
    assert not hasattr(config.field, "hash") and not hasattr(config.field.encoding, "levels")
    with pytest.raises(
        RequestError, match=r"^field\.hash\.levels 8: not used by this engine: its field\.encoding is"
    ) as no:
        config.with_settings(hash_levels=8)
    assert "\n" not in str(no.value)
    assert "hash_levels" not in config.flat() and config.flat()["plane_resolutions"] == (64, 128)


@pytest.mark.parametrize(
    "preset, choice, part, other",
    [
        ("nerfacto-cpu", {"field": {"encoding": "kplanes"}}, ("field", "planes"), ("field", "hash", "levels")),
        ("cpu", {"field": {"encoding": "hash"}}, ("field", "hash"), ("field", "planes", "features")),
        ("paper", {"sampler": {"kind": "occupancy"}}, ("sampler", "occupancy"), ("sampler", "proposal", "samples")),
        ("test", {"sampler": {"kind": "proposal"}}, ("sampler", "proposal"), ("sampler", "occupancy", "resolution")),
    ],
)
def test_another_part_chosen_over_a_preset_comes_with_its_own_defaults(preset, choice, part, other):
    config = Engine.of(preset, choice).config
    chosen = names.get(config, part)
    assert type(chosen)() == chosen  # the part's type's defaults, not the preset's part's settings
    assert names.unused(config, other)  # the preset's own part is gone with its settings
    assert config == NerfConfig.preset(preset).changed(
        {(*part[:1], "encoding" if part[0] == "field" else "kind"): chosen.NAME}
    )


def test_a_record_that_holds_every_parts_settings_still_reads():
    """session.json and config.json written before the choices were types hold both parts' groups."""
    old = {
        "field": {"encoding": "hash", "hash": {"levels": 6}, "planes": {"resolutions": [64, 256], "features": 8}},
        "sampler": {"kind": "occupancy", "occupancy": {"resolution": 32}, "proposal": {"samples": [256, 96]}},
    }
    config = NerfConfig.from_dict(old)
    assert config.field.encoding == HashGridConfig(levels=6) and config.sampler.kind.resolution == 32
    with pytest.raises(ValueError, match="unknown setting 'levelz'"):  # the other part's names are still checked
        NerfConfig.from_dict({"field": {"encoding": "kplanes", "hash": {"levelz": 6}}})
    with pytest.raises(ValueError, match="unknown encoding 'grid'; choose one of: hash, kplanes"):
        NerfConfig.from_dict({"field": {"encoding": "grid"}})
