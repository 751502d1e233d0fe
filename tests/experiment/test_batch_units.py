"""How a sweep hands out its runs: one at a time, or trial batches of one engine configuration in
plan order; and the batched engine's version in the fingerprint (a cell never mixes versions)."""

import pytest

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.store import RunKey
from nerfaug.experiment.sweep import check_config, plan_runs, plan_units
from nerfaug.nerf.encoding import HashEncoding


def test_batches_hold_runs_of_one_engine_configuration_in_plan_order():
    config = ExperimentConfig(
        scenes=("lego", "chair"), methods=("ours", "uniform"), trials=3, engine="nerfacto-cpu", batch=4
    )
    todo = plan_runs(config)
    units = plan_units(todo, config, 4)
    # chair trains with another field learning rate (the paper's): never in a batch with lego.
    for unit in units:
        assert len(unit) <= 4 and len({key.scene for key in unit}) == 1
    assert [key for unit in units for key in sorted(unit, key=todo.index)] == sorted(todo, key=todo.index)
    assert units[0] == [RunKey("lego", m, t) for t in (0, 1) for m in ("ours", "uniform")]
    # Alone: one run a unit.
    alone = config.replace(batch=1)
    assert plan_units(todo, alone, 4) == [[key] for key in todo]


def test_the_batched_engine_is_its_own_engine_version(monkeypatch):
    monkeypatch.setattr(HashEncoding, "default_kernel", "torch")  # the reference engine (NERFAUG_HASH_KERNEL=torch)
    cpu = ExperimentConfig(engine="nerfacto-cpu", device="cpu")
    assert not cpu.batched() and "engine_version" not in cpu.fingerprinted()  # earlier results stay valid
    batched = cpu.replace(batch=4)
    assert batched.batched() and batched.fingerprinted()["engine_version"] == "batched-1"
    # The size of a batch is not part of a run's identity; only the engine is.
    assert batched.fingerprinted() == cpu.replace(batch=8).fingerprinted()
    # Auto: batches on a GPU, for engines that batch.
    assert cpu.replace(device="cuda").batched() and not ExperimentConfig(engine="cpu", device="cuda").batched()


def test_a_batch_of_an_engine_that_cannot_batch_is_refused_by_name():
    with pytest.raises(ValueError, match=r"--batch 4: engine 'cpu': trial batches need the proposal sampler"):
        check_config(ExperimentConfig(engine="cpu", batch=4))
    with pytest.raises(ValueError, match="--batch -1"):
        check_config(ExperimentConfig(engine="nerfacto-cpu", batch=-1))
