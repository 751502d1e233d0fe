"""The health check: a NeRF that renders its training views as background only, or as flat colour,
is found empty (saying which test failed), one that learned them is not, renders of untrained poses
are reported, and a proposal from an empty one is refused or warns."""

import math
import warnings

import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data.views import Views
from nerfaug.health import EmptyModelWarning, Health, model_health
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.trainer import Trainer

RED, WHITE = torch.tensor([0.8, 0.1, 0.1]), torch.ones(3)


def ball_cameras(azimuths, polars, size: int = 16) -> Cameras:
    poses = pose_from_angles(torch.tensor(azimuths), torch.tensor(polars))
    return Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)


def render_ball(cameras: Cameras, index: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The red ball of radius 0.8 at the origin over white, seen by camera `index`: (H, W, 3)
    colours and the (H, W) mask of the rays that hit it."""
    origins, directions = image_rays(cameras, index)
    b = (origins * directions).sum(-1)
    hit = b * b - (origins.square().sum(-1) - 0.64) > 0
    colour = torch.where(hit[:, None], RED, WHITE)
    return colour.reshape(cameras.height, cameras.width, 3), hit.reshape(cameras.height, cameras.width)


def ball_views(size: int = 16) -> Views:
    """The ball from four sides."""
    cameras = ball_cameras([0.0, 1.6, 3.2, 4.8], [0.9, 1.1, 0.9, 1.1], size)
    images = [render_ball(cameras, i)[0] for i in range(len(cameras))]
    return Views(cameras, torch.stack(images), [f"r_{i}" for i in range(len(cameras))])


class StandIn:
    """A model object the check accepts (`background`, `render_image`), rendering what `draw`
    gives for (cameras, index): (rgb (H, W, 3), accumulation (H, W))."""

    background = torch.ones(3)

    def __init__(self, draw):
        self.draw = draw

    def render_image(self, cameras, index):
        rgb, accumulation = self.draw(cameras, index)
        return {"rgb": rgb, "accumulation": accumulation}


def flat(colours):
    """A stand-in rendering view `index` as the one colour `colours(index)` (RGB), fully opaque."""
    return StandIn(
        lambda c, i: (colours(i).reshape(1, 1, 3).expand(c.height, c.width, 3), torch.ones(c.height, c.width))
    )


def good_ball():
    """A stand-in that renders the ball as it is, from any pose."""
    return StandIn(lambda c, i: (lambda rgb, hit: (rgb, hit.float()))(*render_ball(c, i)))


def test_a_nerf_rendering_the_mean_colour_is_empty_and_one_rendering_the_images_is_not():
    views = ball_views()
    mean = views.images.reshape(-1, 3).mean(0)  # the set's per-channel mean colour
    health = model_health(flat(lambda i: mean), views)
    # Opaque over the object, and above the blank image by more than the former fixed +0.5 dB:
    # the old check passed it. Against the mean-colour baseline it scores nothing.
    assert health.object_opacity == 1.0 and health.psnr > health.blank_psnr + 0.5
    assert health.psnr <= health.mean_psnr + 1e-6
    assert health.empty and health.reason == "flat", health  # +1.2 dB over blank: past that test too
    assert f"({health.reason}:" in health.line() and "another --seed" in health.line()
    # Each view's own mean colour (a flat colour changing with the view) scores the baseline exactly.
    own = model_health(flat(lambda i: views.image(i).reshape(-1, 3).mean(0)), views)
    assert own.empty and own.psnr == pytest.approx(own.mean_psnr, abs=1e-3)
    good = model_health(good_ball(), views)
    assert not good.empty and good.reason is None and good.psnr > good.mean_psnr + 20.0
    assert "learned its views" in good.line()


def test_the_baselines_are_the_blank_image_and_each_images_mean_colour():
    views = ball_views()
    health = model_health(good_ball(), views)
    images = views.images.float()  # (4, 16, 16, 3): the health check's size already
    blank = -10 * math.log10(float((images - 1.0).square().mean()))
    centred = images - images.mean(dim=(1, 2), keepdim=True)
    assert health.blank_psnr == pytest.approx(blank, abs=1e-4)
    assert health.mean_psnr == pytest.approx(-10 * math.log10(float(centred.square().mean())), abs=1e-4)
    assert health.mean_psnr > health.blank_psnr  # the mean colour is the stricter baseline


def test_untrained_poses_are_reported_not_refused():
    views = ball_views()
    untrained = ball_cameras([0.8, 2.4, 4.0, 5.6, 1.2], [1.0, 0.7, 1.2, 0.8, 1.0])
    good = model_health(good_ball(), views, untrained=untrained)
    assert good.untrained_views == 4 and good.untrained_empty == 0  # UNTRAINED_VIEWS of the five
    assert good.untrained_object_fraction == pytest.approx(good.object_fraction, rel=0.5)
    # Fits its training views exactly and renders nothing elsewhere: reported, still not empty.
    trained = views.cameras.camera_to_world

    def fogged(cameras, index):
        seen = bool((cameras.camera_to_world[index] - trained).abs().amax(dim=(1, 2)).min() < 1e-6)
        rgb, hit = render_ball(cameras, index)
        return (rgb, hit.float()) if seen else (torch.ones_like(rgb), torch.zeros_like(hit, dtype=torch.float32))

    sparse = model_health(StandIn(fogged), views, untrained=untrained)
    assert not sparse.empty and sparse.untrained_empty == 4 and sparse.untrained_object_fraction == 0.0
    assert "learned its views" in sparse.line() and "4 of 4 untrained poses rendered empty" in sparse.line()
    assert model_health(good_ball(), views).untrained_views == 0  # none asked: none rendered
    assert "untrained" not in model_health(good_ball(), views).line()


def test_a_fresh_transparent_nerf_is_empty_and_a_trained_one_is_not():
    views = ball_views()
    config = NerfConfig.preset("test")
    trainer = Trainer(views, config, seed=0, progress=False)
    # Transparent by construction: every density 0 (the density network's output bias very negative).
    fresh = Trainer(views, config, seed=0, progress=False).model
    with torch.no_grad():
        fresh.field.density_mlp[-1].bias[0] = -30.0
    empty = model_health(fresh, views)
    assert empty.empty and empty.object_opacity < 1e-6 and empty.reason == "transparent"
    # The blank image is what an empty NeRF renders: the two PSNRs agree.
    assert empty.psnr == pytest.approx(empty.blank_psnr, abs=0.05)
    assert 0.05 < empty.object_fraction < 0.9
    assert "background only" in empty.line() and "another --seed" in empty.line()
    trainer.train(300)
    untrained = ball_cameras([0.8, 2.4], [1.0, 1.0])
    learned = model_health(trainer.model, views, untrained=untrained)
    assert not learned.empty, learned
    assert learned.object_opacity > 0.5 and learned.psnr > learned.mean_psnr + 3.0
    assert learned.untrained_views == 2 and 0.0 <= learned.untrained_opacity <= 1.0
    assert "learned its views" in learned.line()


def test_the_verdict_by_its_thresholds():
    # Thresholds: opacity 0.05 over the object; a gain of -10 log10(0.8) = 0.97 dB over each baseline.
    base = dict(object_fraction=0.2, object_opacity=0.9, psnr=20.0, blank_psnr=12.0, views=4, mean_psnr=14.0)
    assert not Health(**base).empty and Health(**base).reason is None
    assert Health(**{**base, "object_opacity": 0.01}).reason == "transparent"
    assert Health(**{**base, "psnr": 12.5}).reason == "blank"  # opaque, but no better than a blank image
    assert Health(**{**base, "psnr": 14.5}).reason == "flat"  # +2.5 dB over blank, +0.5 over the mean colour
    assert Health(**{**base, "psnr": 15.2}).reason is None  # +1.2 dB over the mean colour
    # A record made before the mean colour was measured is judged by the blank image alone.
    assert Health(**{**base, "psnr": 14.5, "mean_psnr": None}).reason is None
    # Views without an object (all background) never make a NeRF empty.
    assert not Health(**{**base, "object_fraction": 0.0, "object_opacity": math.nan}).empty
    record = Health(**{**base, "psnr": 14.5}).to_dict()
    assert record["empty"] is True and record["reason"] == "flat"
    assert Health.from_dict(record) == Health(**{**base, "psnr": 14.5})
    nothing = Health(**{**base, "object_fraction": 0.0, "object_opacity": math.nan}).to_dict()
    assert nothing["object_opacity"] is None and math.isnan(Health.from_dict(nothing).object_opacity)


def test_a_proposal_from_an_empty_session_is_refused_unless_allowed(tmp_path):
    from dataclasses import replace

    from nerfaug.capture import CaptureSession, ProposalRequest, SessionSettings
    from nerfaug.data import write_blender_split
    from nerfaug.health import EmptyModel
    from nerfaug.selection import SelectionConfig

    views = ball_views()
    write_blender_split(tmp_path / "data", "train", views)
    session = CaptureSession.create(tmp_path / "data", tmp_path / "run", SessionSettings(engine="test", seed=1))
    with torch.no_grad():
        session.trainer.model.field.density_mlp[-1].bias[0] = -30.0
    request = ProposalRequest(n=2, n_candidates=20, selection=SelectionConfig(entropy_resolution=4))
    with pytest.raises(EmptyModel, match="no views proposed: .*background only.*--allow-empty"):
        session.propose(request, map=False)
    assert session.state.proposals == [] and not (session.run_dir / "proposals").exists()
    with pytest.warns(EmptyModelWarning, match="background only"):
        session.propose(replace(request, allow_empty=True), map=False)
    assert session.state.proposals[-1].model_dump()["empty_model"] is True
    # The record keeps the check, with the candidates (poses never trained on) rendered beside.
    kept = session.state.proposals[-1].health
    assert kept["empty"] is True and kept["reason"] in ("transparent", "blank", "flat")
    assert kept["untrained_views"] == 4 and kept["untrained_empty"] is not None
    session.train(300)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EmptyModelWarning)
        session.propose(request, map=False)
    assert "empty_model" not in session.state.proposals[-1].model_dump()
    assert session.state.proposals[-1].health["reason"] is None


def test_the_service_answers_an_empty_model_with_409():
    from nerfaug.health import EmptyModel
    from nerfaug.service.errors import status_of

    status, line = status_of(EmptyModel("run: no views proposed: the NeRF renders ..."))
    assert status == 409 and line.startswith("run: no views proposed")
    assert EmptyModel("x").exit_code == 1
