"""Per-pixel uncertainty images (`nerfaug.uncertainty.images`): FisherRF's per-pixel gain against
the full Jacobian, its sum against the view's FisherRF score, and the entropy image against the
view's mean entropy."""

import importlib.util
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.uncertainty.entropy import mean_view_entropy
from nerfaug.uncertainty.fisher import FISHER_LAMBDA, fisher_views, fisherrf_scores, n_trainable
from nerfaug.uncertainty.images import fisher_pixel_scores, view_images
from nerfaug.uncertainty.rays import reduced_cameras, views_rays

_spec = importlib.util.spec_from_file_location("unc_fisher_helpers", Path(__file__).with_name("test_fisher.py"))
helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(helpers)


def camera(width: int, height: int, azimuth: float = 0.7, polar: float = 0.9) -> Cameras:
    pose = pose_from_angles(torch.tensor([azimuth]), torch.tensor([polar]), 4.0)
    return Cameras.from_fov(pose.float(), BLENDER_CAMERA_ANGLE_X, width, height)


def test_each_pixels_fisher_score_is_its_exact_information_gain():
    model = helpers.TinyNerf()
    cameras = camera(3, 2)
    h_train = torch.rand(n_trainable(model), generator=torch.Generator().manual_seed(1)) * 0.1
    scores = fisher_pixel_scores(model, cameras, h_train, batch=4)
    assert scores.shape == (2, 3)
    origins, directions = views_rays(cameras, [0])
    inverse = 1.0 / (h_train + FISHER_LAMBDA)
    expected = torch.stack(
        [helpers.full_jacobian_diagonal(model, origins[i : i + 1], directions[i : i + 1]) @ inverse for i in range(6)]
    )
    torch.testing.assert_close(scores.reshape(-1), expected, rtol=1e-4, atol=1e-6)


def test_the_fisher_image_sums_to_the_views_fisherrf_score():
    model = helpers.TinyNerf(seed=2)
    cameras = camera(4, 3, azimuth=2.0)
    h_train = torch.rand(n_trainable(model), generator=torch.Generator().manual_seed(3))
    scores = fisher_pixel_scores(model, cameras, h_train)
    whole = fisher_views(model, cameras, resolution=cameras.width, method="exact")
    torch.testing.assert_close(scores.sum(), fisherrf_scores(h_train, whole)[0], rtol=1e-4, atol=1e-6)


def test_the_entropy_image_averages_to_the_views_mean_entropy():
    torch.manual_seed(0)
    model = NerfModel(NerfConfig.preset("test"), background=(1.0, 1.0, 1.0))
    cameras = camera(16, 12)
    small = reduced_cameras(cameras, 6)
    images = view_images(model, small, 0)
    assert images["rgb"].shape == (small.height, small.width, 3)
    assert images["entropy"].shape == images["depth"].shape == (small.height, small.width)
    assert (images["rgb"] >= 0).all() and (images["rgb"] <= 1).all() and (images["entropy"] >= 0).all()
    expected = mean_view_entropy(model, cameras, resolution=6)[0]
    assert float(images["entropy"].mean()) == pytest.approx(float(expected), rel=1e-5, abs=1e-6)
