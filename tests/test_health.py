"""The health check: a NeRF that renders its training views as background only is found empty, one
that learned them is not, and a proposal from an empty one warns; runs record it and the study's
page counts such runs per cell."""

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


def ball_views(size: int = 16) -> Views:
    """A red ball of radius 0.8 at the origin, over white, from four sides."""
    poses = pose_from_angles(torch.tensor([0.0, 1.6, 3.2, 4.8]), torch.tensor([0.9, 1.1, 0.9, 1.1]))
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
    images = []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        b = (origins * directions).sum(-1)
        hit = b * b - (origins.square().sum(-1) - 0.64) > 0
        colour = torch.where(hit[:, None], torch.tensor([0.8, 0.1, 0.1]), torch.ones(3))
        images.append(colour.reshape(size, size, 3))
    return Views(cameras, torch.stack(images), [f"r_{i}" for i in range(len(cameras))])


def test_a_fresh_transparent_nerf_is_empty_and_a_trained_one_is_not():
    views = ball_views()
    config = NerfConfig.preset("test")
    trainer = Trainer(views, config, seed=0, progress=False)
    # Transparent by construction: every density 0 (the density network's output bias very negative).
    fresh = Trainer(views, config, seed=0, progress=False).model
    with torch.no_grad():
        fresh.field.density_mlp[-1].bias[0] = -30.0
    empty = model_health(fresh, views)
    assert empty.empty and empty.object_opacity < 1e-6
    # The blank image is what an empty NeRF renders: the two PSNRs agree.
    assert empty.psnr == pytest.approx(empty.blank_psnr, abs=0.05)
    assert 0.05 < empty.object_fraction < 0.9
    assert "background only" in empty.line() and "another --seed" in empty.line()
    trainer.train(300)
    learned = model_health(trainer.model, views)
    assert not learned.empty, learned
    assert learned.object_opacity > 0.5 and learned.psnr > learned.blank_psnr + 3.0
    assert "learned its views" in learned.line()


def test_the_verdict_by_its_thresholds():
    base = dict(object_fraction=0.2, object_opacity=0.9, psnr=20.0, blank_psnr=12.0, views=4)
    assert not Health(**base).empty
    assert Health(**{**base, "object_opacity": 0.01}).empty  # transparent over the object
    assert Health(**{**base, "psnr": 12.3}).empty  # opaque, but no better than a blank image
    # Views without an object (all background) never make a NeRF empty.
    assert not Health(**{**base, "object_fraction": 0.0, "object_opacity": math.nan}).empty
    assert Health(**{**base, "psnr": 12.3}).to_dict()["empty"] is True


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
    session.train(300)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EmptyModelWarning)
        session.propose(request, map=False)
    assert "empty_model" not in session.state.proposals[-1].model_dump()


def test_the_service_answers_an_empty_model_with_409():
    from nerfaug.health import EmptyModel
    from nerfaug.service.errors import status_of

    status, line = status_of(EmptyModel("run: no views proposed: the NeRF renders ..."))
    assert status == 409 and line.startswith("run: no views proposed")
    assert EmptyModel("x").exit_code == 1
