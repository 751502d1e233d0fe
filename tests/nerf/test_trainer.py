"""Trainer: it learns, adds views mid-run, resumes bit-identically, is seeded, and stops on NaN."""

import math

import pytest
import torch

from nerfaug.data.views import Views
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.trainer import Trainer, TrainingDiverged, exponential_lr, psnr_from_mse


@pytest.fixture(scope="module")
def views(sphere_views) -> Views:
    return sphere_views([0.0, 1.6, 3.2, 4.8], [0.9, 1.1, 0.9, 1.1])


def views_psnr(trainer: Trainer, views: Views) -> float:
    mses = [
        float((trainer.model.render_image(views.cameras, i)["rgb"] - views.images[i]).square().mean())
        for i in range(len(views))
    ]
    return psnr_from_mse(sum(mses) / len(mses))


def parameters_equal(a: Trainer, b: Trainer) -> bool:
    state_a, state_b = a.model.state_dict(), b.model.state_dict()
    return state_a.keys() == state_b.keys() and all(torch.equal(state_a[k], state_b[k]) for k in state_a)


def test_a_tiny_scene_is_learned(views):
    trainer = Trainer(views, NerfConfig.preset("test"), seed=0, progress=False)
    blank = psnr_from_mse(float((views.images - 1.0).square().mean()))
    trainer.train(300)
    assert trainer.step == 300 and len(trainer.history) == 300
    assert views_psnr(trainer, views) > max(blank + 8.0, 20.0)
    # The occupancy grid has left warm-up and culled empty space.
    assert 0 < trainer.model.sampler.grid.occupied.float().mean() < 0.9


def test_add_views_samples_the_new_pixels_and_keeps_the_optimiser_state(views):
    trainer = Trainer(views.subset([0, 1]), NerfConfig.preset("test"), seed=0, progress=False)
    trainer.train(5)
    state_before = {id(p): {k: v for k, v in s.items()} for p, s in trainer.optimizer.state.items()}
    values_before = {id(p): s["exp_avg"].clone() for p, s in trainer.optimizer.state.items()}
    marker = views.subset([2])
    marker.images = torch.zeros_like(marker.images)
    marker.images[..., 0] = 1.0  # pure red: no pixel of the first views has exactly this colour
    trainer.add_views(marker)

    assert len(trainer.train_views) == 3 and trainer.step == 5
    for p, s in trainer.optimizer.state.items():
        assert s["exp_avg"] is state_before[id(p)]["exp_avg"]
        assert torch.equal(s["exp_avg"], values_before[id(p)])
    new_origin = marker.cameras.positions[0]
    hits = 0
    for _ in range(10):
        origins, _, target, _ = trainer.sample_batch()
        from_new = (origins - new_origin).norm(dim=-1) < 1e-5
        assert torch.equal(from_new, (target == torch.tensor([1.0, 0.0, 0.0])).all(-1))
        hits += int(from_new.sum())
    # Uniform over all pixels: about a third of the rays now come from the new view.
    assert 0.2 < hits / (10 * trainer.config.optimiser.batch_size) < 0.45
    trainer.train(8)


def test_add_views_rejects_another_image_size(views, sphere_views):
    trainer = Trainer(views, NerfConfig.preset("test"), progress=False)
    with pytest.raises(ValueError, match="resize"):
        trainer.add_views(sphere_views([0.5], [1.0], size=8))


def test_same_seed_same_weights_other_seed_other_weights(views):
    config = NerfConfig.preset("test")
    a, b, c = (Trainer(views, config, seed=s, progress=False) for s in (1, 1, 2))
    for trainer in (a, b, c):
        trainer.train(12)
    assert parameters_equal(a, b) and a.history == b.history
    assert not parameters_equal(a, c)


def test_checkpoint_round_trip_continues_bit_identically(views, tmp_path):
    config = NerfConfig.preset("test", random_background=True)
    straight = Trainer(views.subset([0, 1, 2]), config, seed=3, progress=False)
    straight.train(6)
    straight.add_views(views.subset([3]))
    straight.train(20)  # crosses the occupancy warm-up (8) and several grid updates

    resumed = Trainer(views.subset([0, 1, 2]), config, seed=3, progress=False)
    resumed.train(6)
    resumed.add_views(views.subset([3]))
    resumed.train(10)
    path = resumed.save_checkpoint(tmp_path / "run" / "ckpt.pt")
    assert not list(path.parent.glob("*.tmp"))
    loaded = Trainer.load_checkpoint(path, progress=False)
    assert loaded.step == 10 and loaded.train_views.names == resumed.train_views.names
    loaded.train(20)
    assert parameters_equal(straight, loaded)
    assert straight.history == loaded.history
    for (_, sa), (_, sb) in zip(straight.optimizer.state.items(), loaded.optimizer.state.items()):
        assert torch.equal(sa["exp_avg_sq"], sb["exp_avg_sq"])


def test_nan_loss_raises_and_keeps_the_last_good_checkpoint(views, tmp_path):
    trainer = Trainer(views, NerfConfig.preset("test"), progress=False)
    path = tmp_path / "ckpt.pt"
    trainer.train(4, checkpoint=path, checkpoint_every=2)
    with torch.no_grad():
        trainer.model.field.density_mlp[-1].bias.fill_(float("nan"))
    with pytest.raises(TrainingDiverged, match=r"step 4: loss = nan.*ckpt\.pt") as error:
        trainer.train(8, checkpoint=path, checkpoint_every=2)
    assert error.value.step == 4 and error.value.checkpoint == path
    good = Trainer.load_checkpoint(path, progress=False)
    assert good.step == 4
    assert all(torch.isfinite(p).all() for p in good.model.parameters())


def test_learning_rate_decays_exponentially_between_its_ends():
    assert exponential_lr(1e-2, 1e-4, 0, 200) == pytest.approx(1e-2)
    assert exponential_lr(1e-2, 1e-4, 100, 200) == pytest.approx(1e-3)
    assert exponential_lr(1e-2, 1e-4, 400, 200) == pytest.approx(1e-4)


def test_field_and_proposal_groups_get_their_own_learning_rates(views):
    config = NerfConfig.preset(
        "test",
        encoding="hash",
        sampler="proposal",
        hash_levels=2,
        hash_log2_table_size=8,
        proposal_samples=(8,),
        proposal_max_resolutions=(32,),
        proposal_hash_levels=2,
        proposal_log2_table_size=8,
        field_lr=2e-3,
        lr=1e-2,
    )
    trainer = Trainer(views, config, progress=False)
    trainer.train(2)
    lrs = {g["name"]: g["lr"] for g in trainer.optimizer.param_groups}
    assert lrs["field"] == pytest.approx(exponential_lr(2e-3, 1e-4, 1, config.optimiser.lr_decay_steps))
    assert lrs["proposal"] == pytest.approx(exponential_lr(1e-2, 1e-4, 1, config.optimiser.lr_decay_steps))


def test_presets_and_config_round_trip():
    for name in ("cpu", "paper", "test"):
        config = NerfConfig.preset(name)
        assert NerfConfig.from_dict(config.to_dict()) == config
    paper = NerfConfig.preset("paper")
    assert (
        paper.field.encoding.levels,
        paper.field.encoding.features_per_level,
        paper.field.encoding.log2_table_size,
    ) == (
        16,
        2,
        19,
    )
    assert (paper.optimiser.batch_size, paper.optimiser.adam_eps, paper.field.average_init_density) == (
        4096,
        1e-15,
        0.01,
    )
    assert NerfConfig.preset("paper", field_lr=0.002).optimiser.field_lr == 0.002
    with pytest.raises(ValueError, match="unknown engine preset .fast."):
        NerfConfig.preset("fast")
    with pytest.raises(ValueError, match="near"):
        NerfConfig().with_settings(near=3.0, far=2.0)
    assert math.isclose(psnr_from_mse(0.01), 20.0)


@pytest.mark.rounding
def test_compiled_networks_train_like_the_pure_path(sphere_views):
    """`Trainer(compile=backend)` compiles the field and the sampler's networks in place: with the
    "eager" backend (the same kernels) the losses are the pure path's, and the state-dict keys
    (hence checkpoints) are unchanged."""
    views = sphere_views([0.0, 1.5, 3.0], [0.8, 0.9, 1.0], size=8)
    for preset in ("test", "nerfacto-cpu"):
        config = NerfConfig.preset(preset, batch_size=64)
        pure = Trainer(views, config, seed=3, progress=False)
        compiled = Trainer(views, config, seed=3, progress=False, compile="eager")
        assert compiled.model.state_dict().keys() == pure.model.state_dict().keys()
        networks = [compiled.model.field, *getattr(compiled.model.sampler, "networks", [])]
        assert all(m._compiled_call_impl is not None for m in networks)  # really compiled
        assert pure.model.field._compiled_call_impl is None
        losses = [[t.train_step()["loss"] for _ in range(4)] for t in (pure, compiled)]
        # Equal here; compiled code may order a sum otherwise on another CPU, and four steps cannot
        # amplify a last-bit difference to 1e-5, while a wrong network moves the loss by percents.
        assert losses[0] == pytest.approx(losses[1], rel=1e-5), preset


def test_each_loss_is_kept_by_name_and_they_sum_to_the_loss(views):
    """A collapse is debugged loss by loss: every history entry names the photometric error and the
    proposal sampler's distortion and interlevel losses, whose sum (in that order) is the loss."""
    from .test_model import TINY_PROPOSAL

    trainer = Trainer(views, NerfConfig.preset("test", **TINY_PROPOSAL), seed=0, progress=False)
    trainer.train(6)
    for entry in trainer.history:
        losses = entry["losses"]
        assert list(losses) == ["rgb", "distortion", "interlevel"] and all(v >= 0 for v in losses.values())
        assert entry["loss"] == pytest.approx(losses["rgb"] + (losses["distortion"] + losses["interlevel"]), rel=1e-6)
        assert entry["psnr"] == psnr_from_mse(losses["rgb"])
    assert all(value > 0 for value in trainer.history[-1]["losses"].values())
    occupancy = Trainer(views, NerfConfig.preset("test"), seed=0, progress=False)
    entry = occupancy.train_step()
    assert list(entry["losses"]) == ["rgb"] and entry["loss"] == pytest.approx(entry["losses"]["rgb"], rel=1e-6)
