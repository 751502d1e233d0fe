"""A run's memory estimated from its engine's settings (`nerfaug.nerf.footprint`): the parameter
count against the built models', the presets fitting a small machine, and a refusal that names the
setting that makes a run too large."""

import pytest
import torch

from nerfaug.nerf.config import PRESETS, NerfConfig
from nerfaug.nerf.engine import Engine
from nerfaug.nerf.footprint import check_engine_fits, estimated_bytes, machine_memory, parameters
from nerfaug.nerf.trainer import seeded_model
from nerfaug.schema import RequestError

GIB = 2**30


@pytest.mark.parametrize("name", ["test", "cpu", "nerfacto-cpu", "test+encoding=hash+hash_levels=4"])
def test_the_parameter_count_bounds_the_built_models_within_a_third(name):
    config = NerfConfig.preset(name)
    model = seeded_model(config, torch.Generator().manual_seed(0))
    built = sum(p.numel() for p in model.parameters())
    assert built <= parameters(config) <= 1.34 * built


def test_every_preset_fits_a_machine_of_4_gib_by_estimate():
    for name, config in PRESETS.items():
        assert estimated_bytes(config) < 4 * GIB, name
        check_engine_fits(Engine.read(name), limit=4 * GIB)


def test_the_estimate_grows_with_each_size_setting():
    base = NerfConfig.preset("test")
    for setting in ("hidden_dim", "batch_size", "num_samples", "render_chunk", "plane_features"):
        bigger = NerfConfig.preset("test").with_settings(**{setting: 64 * base.flat()[setting]})
        assert estimated_bytes(bigger) > estimated_bytes(base), setting


@pytest.mark.parametrize(
    "variant, path, value",
    [
        ("test+hidden_dim=1000000000", "field.hidden_dim", 1_000_000_000),
        ("test+plane_resolutions=100000", "field.planes.resolutions", (100_000,)),
        ("test+batch_size=1000000000", "optimiser.batch_size", 1_000_000_000),
        # Two settings changed: the one that makes it large is named, not the first.
        ("test+color_layers=2+batch_size=1000000000", "optimiser.batch_size", 1_000_000_000),
    ],
)
def test_a_run_too_large_names_the_setting(variant, path, value):
    with pytest.raises(RequestError, match="by estimate, more than this machine's") as refused:
        check_engine_fits(Engine.read(variant))
    assert (refused.value.argument, refused.value.value) == (path, value)


def test_a_preset_too_large_for_a_machine_names_the_engine():
    expected = "^engine 'paper': one run of this engine needs about 2.* more than this machine's 1.0 GiB"
    with pytest.raises(ValueError, match=expected):
        check_engine_fits(Engine.read("paper"), limit=GIB)


def test_this_machines_memory_is_read():
    with open("/proc/meminfo") as info:
        total = int(next(line for line in info if line.startswith("MemTotal:")).split()[1]) * 1024
    assert 0 < machine_memory() <= total
