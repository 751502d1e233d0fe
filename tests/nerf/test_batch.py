"""Batches of runs: one `Trainer` trains K runs in lockstep, each from its own seed, views and
random numbers, each computed as it would be alone; a diverging run stops alone; a batch
checkpoints and resumes; every engine feature works at any batch size."""

import math

import pytest
import torch

from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.trainer import Trainer

# Each test here compares a batch with runs alone (`make test-rounding` runs them under several
# CPU kernels and thread counts): the tolerances do not hinge on last bits.
pytestmark = pytest.mark.rounding

# A small nerfacto-like engine (hash grid, proposal sampler), cheap enough for unit tests.
SMALL = NerfConfig.preset(
    "nerfacto-cpu",
    hash_levels=4,
    hash_log2_table_size=10,
    hash_max_resolution=64,
    proposal_log2_table_size=9,
    proposal_samples=(16, 8),
    num_samples=8,
    batch_size=64,
)
ENGINES = {
    "nerfacto-cpu": NerfConfig.preset("nerfacto-cpu", batch_size=128),
    "test": NerfConfig.preset("test"),  # the occupancy-grid sampler
    "kplanes": SMALL.with_settings(encoding="kplanes", plane_resolutions=(8, 16)),
}


@pytest.fixture(scope="module")
def views_pair(sphere_views):
    return [
        sphere_views([0.0, 1.6, 3.2], [0.9, 1.1, 0.9]),
        sphere_views([0.5, 2.1, 3.7, 5.0], [1.0, 0.8, 1.2, 1.0]),
    ]


def rays(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    origins = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1) * 4.0
    target = 0.3 * torch.randn(n, 3, generator=g)
    return origins, torch.nn.functional.normalize(target - origins, dim=-1)


def losses(history) -> list[float]:
    return [e["loss"] for e in history]


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_each_run_of_a_batch_trains_as_the_same_run_alone(engine, views_pair):
    """60 steps, before training turns chaotic (rounding differences grow after ~80): each run's
    losses and renders agree with the same run alone to 1e-5."""
    config, seeds, steps = ENGINES[engine], [3, 8], 60
    batch = Trainer(views_pair, config, seeds, progress=False)
    batch.train(steps)
    for k, seed in enumerate(seeds):
        alone = Trainer(views_pair[k], config, seed=seed, progress=False)
        alone.train(steps)
        assert len(batch.runs[k].history) == steps
        assert losses(batch.runs[k].history) == pytest.approx(losses(alone.history), rel=1e-5)
        o, d = rays(25, 40 + k)
        torch.testing.assert_close(
            batch.runs[k].model.render_rays(o, d).rgb, alone.model.render_rays(o, d).rgb, atol=1e-5, rtol=1e-5
        )
    # Different seeds and views, different runs: a mix-up of runs would not pass the checks above.
    assert losses(batch.runs[0].history)[-1] != pytest.approx(losses(batch.runs[1].history)[-1], rel=1e-3)


def test_a_run_is_the_same_whatever_shares_its_batch(views_pair):
    """A run's numbers come from its own generator: in a batch of one or of two, the same."""
    pair = Trainer(views_pair, SMALL, [3, 8], progress=False)
    single = Trainer(views_pair[1:], SMALL, [8], progress=False)
    pair.train(8)
    single.train(8)
    assert losses(pair.runs[1].history) == pytest.approx(losses(single.runs[0].history), rel=1e-5)
    # A batch of one is a run alone: the single run's attributes answer.
    assert single.history is single.runs[0].history and single.model is single.runs[0].model


def test_views_added_to_one_run_change_that_run_only(views_pair, sphere_views):
    batch = Trainer(views_pair, SMALL, [3, 8], progress=False)
    other = Trainer(views_pair, SMALL, [3, 8], progress=False)
    batch.train(4)
    other.train(4)
    batch.add_views(sphere_views([4.0], [0.7]), run=0)
    assert len(batch.runs[0].train_views) == 4 and len(batch.runs[1].train_views) == 4
    batch.train(8)
    other.train(8)
    assert losses(batch.runs[1].history) == losses(other.runs[1].history)
    assert losses(batch.runs[0].history)[4:] != losses(other.runs[0].history)[4:]


def test_a_diverging_run_stops_alone(views_pair):
    batch = Trainer(views_pair, SMALL, [3, 8], progress=False)
    reference = Trainer(views_pair, SMALL, [3, 8], progress=False)
    batch.train(3)
    reference.train(3)
    with torch.no_grad():  # run 0's colour network breaks
        batch.runs[0].model.field.color_mlp[-1].weight.fill_(float("nan"))
    entry = batch.train_step()
    assert entry["runs"][0] is None and entry["runs"][1] is not None
    assert str(batch.failure(0)).startswith("training diverged at step 3: loss = nan")
    assert batch.failure(1) is None
    batch.train(8)
    reference.train(8)
    # Run 1 goes on exactly as if run 0 had not failed.
    assert losses(batch.runs[1].history) == losses(reference.runs[1].history)
    assert len(batch.runs[0].history) == 3
    assert all(math.isfinite(e["loss"]) for e in batch.runs[1].history)
    # When no run is left, training stops with the last failure.
    with torch.no_grad():
        batch.runs[1].model.field.color_mlp[-1].weight.fill_(float("nan"))
    with pytest.raises(RuntimeError, match="training diverged at step 8"):
        batch.train(10)


def test_a_batch_checkpoint_resumes_every_run_exactly(views_pair, tmp_path):
    path = tmp_path / "batch.pt"
    straight = Trainer(views_pair, ENGINES["test"], [3, 8], progress=False)
    straight.train(10)
    first = Trainer(views_pair, ENGINES["test"], [3, 8], progress=False)
    first.train(5, checkpoint=path)
    resumed = Trainer.load_checkpoint(path, progress=False)
    assert len(resumed) == 2 and resumed.step == 5 and [r.seed for r in resumed.runs] == [3, 8]
    resumed.train(10)
    for k in range(2):
        # On the CPU a resumed run is the same run, bit for bit (as a run alone is).
        assert losses(resumed.runs[k].history) == losses(straight.runs[k].history)
        assert len(resumed.runs[k].train_views) == len(views_pair[k])


def test_a_batch_checkpoint_keeps_a_failed_run_stopped(views_pair, tmp_path):
    batch = Trainer(views_pair, SMALL, [3, 8], progress=False)
    batch.train(2)
    with torch.no_grad():
        batch.runs[0].model.field.color_mlp[-1].weight.fill_(float("nan"))
    batch.train(4, checkpoint=tmp_path / "batch.pt")
    resumed = Trainer.load_checkpoint(tmp_path / "batch.pt", progress=False)
    assert str(resumed.failure(0)).startswith("training diverged at step 2") and resumed.failure(1) is None
    resumed.train(6)
    assert len(resumed.runs[0].history) == 2 and len(resumed.runs[1].history) == 6


def test_a_batch_refuses_in_one_line_what_is_one_runs(views_pair):
    batch = Trainer(views_pair, SMALL, [3, 8], progress=False)
    with pytest.raises(AttributeError, match=r"a batch of 2 runs has no single model: read trainer.runs\[k\].model"):
        _ = batch.model
    with pytest.raises(ValueError, match="one seed per run: 2 view sets, 3 seeds"):
        Trainer(views_pair, SMALL, [1, 2, 3], progress=False)
    field = Trainer(views_pair[0], SMALL, progress=False).model.field
    with pytest.raises(ValueError, match="a batch of 2 runs builds each run's field by name"):
        Trainer(views_pair, SMALL, [1, 2], field=field, progress=False)


def test_a_batch_compiles_every_runs_networks(views_pair):
    """`compile` at any batch size: each run's field and sampler networks compiled ("eager": the
    same kernels), training as the pure path does."""
    pure = Trainer(views_pair, SMALL, [3, 8], progress=False)
    compiled = Trainer(views_pair, SMALL, [3, 8], progress=False, compile="eager")
    for run in compiled.runs:
        assert all(m._compiled_call_impl is not None for m in [run.model.field, *run.model.sampler.networks])
    pure.train(4)
    compiled.train(4)
    for k in range(2):
        assert losses(compiled.runs[k].history) == pytest.approx(losses(pure.runs[k].history), rel=1e-5)


def test_a_batch_trains_under_autocast_with_a_scaler_per_run(views_pair):
    """Half precision at any batch size (cuda in use; here the CPU's bfloat16 through the same code
    path): float32 parameters, each run learning; a float16 batch gives each run its own loss
    scaler, so one run's overflow skips no other run's step."""
    batch = Trainer(views_pair, NerfConfig.preset("test"), [3, 8], progress=False)
    batch._autocast = torch.bfloat16  # the cuda code path, with the CPU's autocast dtype
    batch.train(40)
    for run in batch.runs:
        values = losses(run.history)
        assert all(math.isfinite(v) for v in values) and sum(values[-10:]) < 0.8 * sum(values[:10])
        assert all(p.dtype == torch.float32 for p in run.model.parameters())
        assert run.scaler is None  # bfloat16 needs none; float16 (cuda) gets one per run below
    if torch.cuda.is_available():
        half = Trainer(views_pair, SMALL, [3, 8], device="cuda", precision="fp16", progress=False)
        assert len({id(run.scaler) for run in half.runs}) == 2


def test_a_runs_memory_estimate_grows_with_the_engine_and_shrinks_with_fused_kernels():
    from nerfaug.nerf.batch_size import estimated_run_bytes
    from nerfaug.nerf.trainer import seeded_model

    paper, small = NerfConfig.preset("paper"), NerfConfig.preset("nerfacto-cpu")
    assert estimated_run_bytes(paper, fused=True) > 20 * estimated_run_bytes(small, fused=True)
    assert estimated_run_bytes(paper, fused=False) > estimated_run_bytes(paper, fused=True)
    # At least the parameters with their gradients and Adam's two moments.
    params = sum(p.numel() for p in seeded_model(small, torch.Generator().manual_seed(0)).parameters())
    assert estimated_run_bytes(small, fused=True) > 16 * params
