"""Every engine setting's bounds: no float setting takes inf or nan, and a setting the engine does
not read is refused rather than naming a new engine that trains as the old one."""

import math

import pytest

from nerfaug.nerf.config import FLAT_NAMES, NerfConfig, parse_variant
from nerfaug.nerf.engine import Engine
from nerfaug.schema import RequestError


def _float_settings() -> list[str]:
    """Flat names of the settings whose default is a float (read from the dataclasses' values, not
    from the bound types under test)."""
    config = NerfConfig()
    found = []
    for flat, path in FLAT_NAMES.items():
        value = config
        for name in path:
            value = getattr(value, name)
        if isinstance(value, float):
            found.append(flat)
    return found


def test_the_float_settings_are_all_found():
    assert {"field_lr", "far", "near", "box_half_size", "lr", "adam_eps"} <= set(_float_settings())
    assert len(_float_settings()) >= 15


@pytest.mark.parametrize("flat", _float_settings())
@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan])
def test_no_float_setting_takes_inf_or_nan(flat, value):
    with pytest.raises(ValueError) as refused:  # a RequestError, or a group's check of its settings together
        NerfConfig().with_settings(**{flat: value})
    assert FLAT_NAMES[flat][-1] in str(refused.value)


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
    assert NerfConfig.preset("test+encoding=hash+hash_levels=8").field.hash.levels == 8
