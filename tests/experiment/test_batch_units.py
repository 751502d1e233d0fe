"""How a sweep hands out its runs: one at a time, or batches of one engine configuration in plan
order; a batch is the engine of a run alone (its size sets no run apart)."""

import pytest

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.store import RunKey
from nerfaug.experiment.sweep import batch_size, check_config, plan_runs, plan_units
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
    assert plan_units(todo, alone, batch_size(alone, len(todo))) == [[key] for key in todo]


def test_a_batch_is_the_engine_of_a_run_alone(monkeypatch):
    """A run computes the same numbers in a batch of any size as alone: the batch's size is no
    part of its fingerprint, and no engine version sets batches apart."""
    monkeypatch.setattr(HashEncoding, "default_kernel", "torch")  # the reference engine (NERFAUG_HASH_KERNEL=torch)
    cpu = ExperimentConfig(engine="nerfacto-cpu", device="cpu")
    assert "engine_version" not in cpu.fingerprinted()  # earlier results stay valid
    for size in (0, 2, 8):
        assert cpu.replace(batch=size).fingerprinted() == cpu.fingerprinted()
    # One place decides a batch's size: given, or on a CPU by itself one run.
    assert batch_size(cpu, 10) == 1 and batch_size(cpu.replace(batch=4), 10) == 4
    # The fused CPU loop is its own version, at any batch size too.
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    if HashEncoding.cpu_loop_selected():
        assert cpu.fingerprinted()["engine_version"] == cpu.replace(batch=4).fingerprinted()["engine_version"]


@pytest.mark.parametrize("engine", ["cpu", "test", "nerfacto-cpu"])
def test_every_engine_batches(engine):
    """Both samplers and both encodings train in batches: no engine is refused a batch."""
    check_config(ExperimentConfig(engine=engine, batch=4, device="cpu"))
    with pytest.raises(ValueError, match="--batch -1"):
        check_config(ExperimentConfig(engine=engine, batch=-1))
