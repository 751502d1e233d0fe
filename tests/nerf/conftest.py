"""Shared scenes of the engine's tests."""

import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data.views import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles


def sphere_views(azimuths, polars, size: int = 12) -> Views:
    """A unit sphere coloured by its normal, over white, ray-cast analytically."""
    cameras = Cameras.from_fov(
        pose_from_angles(torch.tensor(azimuths), torch.tensor(polars)), BLENDER_CAMERA_ANGLE_X, size, size
    )
    images, alphas = [], []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        b = (origins * directions).sum(-1)
        disc = b * b - (origins.square().sum(-1) - 1.0)
        t = -b - disc.clamp_min(0).sqrt()
        hit = disc > 0
        normal = origins + t[:, None] * directions
        colour = torch.where(hit[:, None], 0.5 + 0.45 * normal, torch.ones(1, 3))
        images.append(colour.reshape(size, size, 3))
        alphas.append(hit.float().reshape(size, size))
    return Views(cameras, torch.stack(images), [f"r_{i}" for i in range(len(cameras))], torch.stack(alphas))


@pytest.fixture(name="sphere_views", scope="session")
def sphere_views_fixture():
    """`sphere_views(azimuths, polars, size=12) -> Views`, for tests that build their own views."""
    return sphere_views
