"""Trial batches: K stacked NeRFs render, differentiate and train as the same K runs alone (up to
rounding), each from its own seed, views and random numbers; a diverging run leaves the others."""

import math

import pytest
import torch

from nerfaug.nerf.batch import BatchModel, StackedHashEncoding, StackedKPlanes
from nerfaug.nerf.batch_trainer import BatchTrainer
from nerfaug.nerf.config import NerfConfig, batch_support
from nerfaug.nerf.encoding import HashEncoding, KPlanesEncoding
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.trainer import Trainer, seeded_model

# Each test here compares a batch with runs alone: other arithmetic, whose rounding the CPU's
# kernels and thread count move (`make test-rounding` runs them under several).
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


def trained_models(config: NerfConfig, seeds, steps: int, views) -> list[NerfModel]:
    """Models with some structure (a few steps of training), so outputs are not constant."""
    models = []
    for seed in seeds:
        trainer = Trainer(views, config, seed=seed, progress=False)
        trainer.train(steps)
        models.append(trainer.model)
    return models


@pytest.mark.parametrize(
    "config",
    [
        SMALL,
        SMALL.with_settings(background_mode="last_sample"),
        SMALL.with_settings(encoding="kplanes", plane_resolutions=(8, 16)),
    ],
    ids=["hash", "last_sample", "kplanes"],
)
def test_a_batch_renders_each_run_as_its_model_alone(config, views_pair):
    models = trained_models(config, [1, 2, 3], 15, views_pair[0])
    batch = BatchModel(models).eval()
    per_run = [rays(40, seed) for seed in (10, 11, 12)]
    origins = torch.stack([o for o, _ in per_run])
    directions = torch.stack([d for _, d in per_run])
    with torch.no_grad():
        together = batch(origins, directions)
    for k, (model, (o, d)) in enumerate(zip(models, per_run)):
        with torch.no_grad():
            alone = model.eval()(o, d)
        rows = slice(40 * k, 40 * (k + 1))
        # The first proposal level's weights agree to float rounding; inverse-CDF sampling on a
        # nearly flat histogram moves a later sample by up to 1e-2 for such a difference, and a
        # colour by up to ~2e-4.
        torch.testing.assert_close(
            together.extras["proposal_weights"][0][rows], alone.extras["proposal_weights"][0], atol=1e-7, rtol=1e-5
        )
        torch.testing.assert_close(together.rgb[rows], alone.rgb, atol=1e-3, rtol=1e-3)
        torch.testing.assert_close(together.weights[rows], alone.weights, atol=1e-3, rtol=1e-3)
        torch.testing.assert_close(together.t_starts[rows], alone.t_starts, atol=0.05, rtol=0)
    # The runs differ from each other: a mix-up of runs would not pass the checks above.
    assert not torch.allclose(together.rgb[:40], together.rgb[40:80], atol=1e-2)


def test_each_run_gets_the_gradient_of_its_own_loss(views_pair):
    models = trained_models(SMALL, [4, 5], 10, views_pair[0])
    batch = BatchModel(models)
    g = torch.Generator().manual_seed(0)
    points, directions = torch.rand(2, 7, 5, 3, generator=g), torch.randn(2, 7, 3, generator=g)
    directions = torch.nn.functional.normalize(directions, dim=-1)
    weights = torch.rand(2, 7, 5, 3, generator=g)  # a loss that reaches every output

    def loss_of(density, rgb, proposal):
        return (density * weights[..., 0]).sum() + (rgb * weights).sum() + (proposal * weights[..., 1]).sum()

    density, geometry = batch.field.density(points.reshape(2, 35, 3))
    rgb = batch.field.color(geometry.reshape(2, 7, 5, -1), directions)
    proposal = batch.networks[0](points.reshape(2, 35, 3))
    loss_of(density.reshape(2, 7, 5), rgb, proposal.reshape(2, 7, 5)).backward()
    for k, model in enumerate(models):
        model.zero_grad()
        d, geo = model.field.density(points[k].reshape(35, 3))
        c = model.field.color(geo, directions[k].repeat_interleave(5, dim=0))
        p = model.sampler.networks[0](points[k].reshape(35, 3))
        (
            (d.reshape(7, 5) * weights[k, ..., 0]).sum()
            + (c.reshape(7, 5, 3) * weights[k]).sum()
            + (p.reshape(7, 5) * weights[k, ..., 1]).sum()
        ).backward()
        rows = batch.field.encoding.rows_per_run
        pairs = [
            (batch.field.encoding.table.grad[k * rows : (k + 1) * rows], model.field.encoding.table.grad),
            (batch.field.density_mlp.layers[0].weight.grad[k], model.field.density_mlp[0].weight.grad.T),
            (batch.field.color_mlp.layers[-1].bias.grad[k, 0], model.field.color_mlp[-1].bias.grad),
            (batch.networks[0].mlp.layers[0].weight.grad[k], model.sampler.networks[0].mlp[0].weight.grad.T),
        ]
        for together, alone in pairs:
            assert alone.abs().max() > 0
            torch.testing.assert_close(together, alone, atol=1e-6, rtol=1e-4)


def test_each_runs_loss_is_its_loss_alone(views_pair):
    models = trained_models(SMALL, [4, 5], 10, views_pair[0])
    batch = BatchModel(models).eval()
    per_run = [rays(30, 20), rays(30, 21)]
    targets = [torch.rand(30, 3, generator=torch.Generator().manual_seed(s)) for s in (30, 31)]
    with torch.no_grad():
        output = batch(torch.stack([o for o, _ in per_run]), torch.stack([d for _, d in per_run]))
        losses, named = batch.run_losses(output, torch.cat(targets))
        for k, (model, (o, d)) in enumerate(zip(models, per_run)):
            alone = model.eval()(o, d)
            own = model.losses(alone, targets[k])
            assert list(named) == list(own) == ["rgb", "distortion", "interlevel"]
            # Sample positions agree to rounding amplified by inverse-CDF sampling (above).
            # The photometric error to rounding; the small auxiliary losses, which the amplified
            # sample positions move most, to a few percent.
            assert float(named["rgb"][k]) == pytest.approx(float(own["rgb"]), rel=1e-3)
            for name in ("distortion", "interlevel"):
                assert float(named[name][k]) == pytest.approx(float(own[name]), rel=0.2), name
            assert float(losses[k]) == pytest.approx(float(sum(own.values())), rel=1e-3)
    assert float(losses[0]) != pytest.approx(float(losses[1]), rel=1e-2)


def test_a_batched_run_trains_as_the_same_run_alone(views_pair):
    seeds = [3, 8]
    batch = BatchTrainer(views_pair, SMALL, seeds, progress=False)
    batch.train(12)
    for k, seed in enumerate(seeds):
        alone = Trainer(views_pair[k], SMALL, seed=seed, progress=False)
        alone.train(12)
        # Same initial parameters and random numbers: the losses agree to rounding.
        together = [e["loss"] for e in batch.runs[k].history]
        assert together == pytest.approx([e["loss"] for e in alone.history], rel=1e-3)
        o, d = rays(25, 40 + k)
        with torch.no_grad():
            torch.testing.assert_close(
                batch.run_model(k).render_rays(o, d).rgb, alone.model.render_rays(o, d).rgb, atol=1e-3, rtol=1e-3
            )
    # Different seeds, different runs.
    assert batch.runs[0].history[-1]["loss"] != batch.runs[1].history[-1]["loss"]


def test_a_run_is_the_same_whatever_shares_its_batch(views_pair):
    """A run's numbers come from its own generator: in a batch of one or of two, the same."""
    pair = BatchTrainer(views_pair, SMALL, [3, 8], progress=False)
    single = BatchTrainer(views_pair[1:], SMALL, [8], progress=False)
    pair.train(8)
    single.train(8)
    assert [e["loss"] for e in pair.runs[1].history] == pytest.approx(
        [e["loss"] for e in single.runs[0].history], rel=1e-5
    )


def test_views_added_to_one_run_change_that_run_only(views_pair, sphere_views):
    batch = BatchTrainer(views_pair, SMALL, [3, 8], progress=False)
    other = BatchTrainer(views_pair, SMALL, [3, 8], progress=False)
    batch.train(4)
    other.train(4)
    batch.add_views(0, sphere_views([4.0], [0.7]))
    assert len(batch.runs[0].views) == 4 and len(batch.runs[1].views) == 4
    batch.train(8)
    other.train(8)
    assert [e["loss"] for e in batch.runs[1].history] == [e["loss"] for e in other.runs[1].history]
    assert [e["loss"] for e in batch.runs[0].history][4:] != [e["loss"] for e in other.runs[0].history][4:]


def test_a_diverging_run_stops_alone(views_pair):
    batch = BatchTrainer(views_pair, SMALL, [3, 8], progress=False)
    reference = BatchTrainer(views_pair, SMALL, [3, 8], progress=False)
    batch.train(3)
    reference.train(3)
    with torch.no_grad():  # run 0's colour network breaks
        batch.model.field.color_mlp.layers[-1].weight[0] = float("nan")
    entries = batch.train_step()
    assert entries[0] is None and entries[1] is not None
    assert str(batch.failure(0)).startswith("training diverged at step 3: loss = nan")
    assert batch.failure(1) is None
    batch.train(8)
    reference.train(8)
    # Run 1 goes on exactly as if run 0 had not failed; no NaN reached any of its parameters.
    assert [e["loss"] for e in batch.runs[1].history] == [e["loss"] for e in reference.runs[1].history]
    assert len(batch.runs[0].history) == 3
    for param in batch.model.parameters():
        assert torch.isfinite(param.view(2, -1)[1]).all()
    assert all(math.isfinite(e["loss"]) for e in batch.runs[1].history)


def test_stacked_encodings_match_their_parts():
    torch.manual_seed(0)
    hashes = [HashEncoding(3, 2, 8, 4, 32) for _ in range(3)]
    planes = [KPlanesEncoding((4, 8), 3) for _ in range(3)]
    x = torch.rand(3, 50, 3)
    for parts, stacked in ((hashes, StackedHashEncoding(hashes)), (planes, StackedKPlanes(planes))):
        together = stacked(x)
        for k, part in enumerate(parts):
            torch.testing.assert_close(together[k], part(x[k]), atol=1e-6, rtol=1e-5)
        copy = type(parts[0])(*((3, 2, 8, 4, 32) if isinstance(parts[0], HashEncoding) else ((4, 8), 3)))
        with torch.no_grad():
            stacked.copy_run_into(2, copy)
        torch.testing.assert_close(copy(x[2]), parts[2](x[2]))


def test_engines_without_the_proposal_sampler_are_refused_by_name():
    assert batch_support(NerfConfig.preset("nerfacto-cpu")) is None
    reason = batch_support(NerfConfig.preset("cpu"))
    assert "proposal sampler" in reason and "'occupancy'" in reason
    models = [seeded_model(NerfConfig.preset("test"), torch.Generator().manual_seed(s)) for s in (0, 1)]
    with pytest.raises(ValueError, match="proposal sampler"):
        BatchModel(models)
    with pytest.raises(ValueError, match="one engine configuration"):
        BatchModel(
            [
                seeded_model(SMALL, torch.Generator().manual_seed(0)),
                seeded_model(NerfConfig.preset("nerfacto-cpu"), torch.Generator().manual_seed(0)),
            ]
        )


def test_the_batched_engine_is_equivalent_to_runs_alone_by_paired_seeds(sphere_views):
    """The acceptance rule of a new engine version, at test size: over paired seeds, the mean
    difference of held-out PSNR inside +-0.2 dB by a TOST at alpha 0.05, and no seed more than
    0.02 dB apart (the full check, at the study's size, is BENCHMARKS.md's "Trial batches").

    60 steps, before training turns chaotic: measured on an AMD EPYC (AVX2 and the default
    kernels), a run batched and alone differ by at most 1e-6 dB up to step 80, 1e-5 at 100 and
    2e-3 at 120; at 150 steps rounding alone moved a seed by 0.2 to 0.6 dB (one CPU's kernels
    against another's), which is what made this test fail on an AVX-512 Xeon. Here 0.02 dB is four
    orders above the rounding and ten times below the seeds' spread, so a run that trained with
    another run's seed, views or random numbers still fails."""
    from nerfaug.equivalence import paired_equivalence

    train = sphere_views([0.0, 1.2, 2.4, 3.6, 4.8], [0.9, 1.1, 0.8, 1.2, 1.0], size=16)
    held_out = sphere_views([0.6, 1.8, 3.0, 4.2], [1.0, 0.9, 1.1, 0.8], size=16)
    seeds, steps = list(range(6)), 60

    def held_out_psnr(model) -> float:
        errors = [
            float((model.render_image(held_out.cameras, i)["rgb"] - held_out.images[i]).square().mean())
            for i in range(len(held_out))
        ]
        return -10.0 * math.log10(sum(errors) / len(errors))

    batch = BatchTrainer([train] * len(seeds), SMALL, seeds, progress=False)
    batch.train(steps)
    together = [held_out_psnr(batch.run_model(k)) for k in range(len(seeds))]
    alone = []
    for seed in seeds:
        trainer = Trainer(train, SMALL, seed=seed, progress=False)
        trainer.train(steps)
        alone.append(held_out_psnr(trainer.model))
    result = paired_equivalence(together, alone, bound=0.2)
    assert result["equivalent"], result
    assert result["max_abs_difference"] <= 0.02, result
    # The runs learned something (an empty field would make every seed equal, and the test
    # vacuous): 12.9 to 13.1 dB at step 60 against 10.3 dB for a blank image.
    blank = -10.0 * math.log10(float((held_out.images - 1.0).square().mean()))
    assert min(alone) > blank + 2.0
    assert max(alone) - min(alone) > 0.1  # the seeds differ (0.23 dB): pairing by seed is what is tested


def test_a_runs_memory_estimate_grows_with_the_engine_and_shrinks_with_fused_kernels():
    from nerfaug.nerf.batch import estimated_run_bytes

    paper, small = NerfConfig.preset("paper"), NerfConfig.preset("nerfacto-cpu")
    assert estimated_run_bytes(paper, fused=True) > 20 * estimated_run_bytes(small, fused=True)
    assert estimated_run_bytes(paper, fused=False) > estimated_run_bytes(paper, fused=True)
    # At least the parameters with their gradients and Adam's two moments.
    params = sum(p.numel() for p in seeded_model(small, torch.Generator().manual_seed(0)).parameters())
    assert estimated_run_bytes(small, fused=True) > 16 * params
