"""Shared scenes of the engine's tests."""

import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data.views import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles
from nerfaug.nerf.trainer import Trainer


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


def engine_numbers(config, steps: int) -> tuple[list[float], object]:
    """What the engine's recorded-number tests pin: `Trainer(views, config, seed=3)` on four
    sphere views, one torch thread, the loss of each of `steps` steps, then the sums of
    `render_weights_only` and `render_rays(...).rgb` over two rays. Returns (numbers, trainer)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        views = sphere_views([0.0, 1.6, 3.2, 4.8], [0.9, 1.1, 0.9, 1.1])
        trainer = Trainer(views, config, seed=3, progress=False)
        trainer.train(steps)
        origins = torch.tensor([[0.0, -4.0, 0.5], [3.0, 3.0, 1.0]])
        directions = -origins / origins.norm(dim=-1, keepdim=True)
        numbers = [e["loss"] for e in trainer.history] + [
            float(trainer.model.render_weights_only(origins, directions).sum()),
            float(trainer.model.render_rays(origins, directions).rgb.sum()),
        ]
    finally:
        torch.set_num_threads(threads)
    return numbers, trainer


@pytest.fixture(name="engine_numbers", scope="session")
def engine_numbers_fixture():
    """`engine_numbers(config, steps) -> (numbers, trainer)`, for the recorded-number tests."""
    return engine_numbers
