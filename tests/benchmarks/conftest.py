"""Shared by the benchmark scripts' tests: the script a test module names, loaded as a module, and
a toy Blender-format dataset (an analytic sphere) with initial, train and test splits, made
without Blender."""

import importlib.util
import sys
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses, sample_uniform_poses


@pytest.fixture(scope="module")
def bench(request):
    """The script `SCRIPT` of the requesting test module, as a module. benchmarks/ holds scripts,
    not a package; it joins sys.path, as it is when a script runs, so scripts import each other."""
    script = request.module.SCRIPT
    if str(script.parent) not in sys.path:
        sys.path.insert(0, str(script.parent))
    spec = importlib.util.spec_from_file_location(script.stem, script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def sphere_views(poses: torch.Tensor, prefix: str, size: int = 24) -> Views:
    """A sphere of radius 0.8 at the origin coloured by its normal, on white, with its alpha."""
    cameras = Cameras.from_fov(poses.float(), BLENDER_CAMERA_ANGLE_X, size, size)
    images, alphas = [], []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        b = (origins * directions).sum(-1)
        disc = b**2 - ((origins**2).sum(-1) - 0.8**2)
        normal = torch.nn.functional.normalize(origins + (-b - disc.clamp_min(0).sqrt())[:, None] * directions, dim=-1)
        hit = (disc > 0).float()
        images.append((hit[:, None] * (0.5 + 0.5 * normal) + (1 - hit[:, None])).reshape(size, size, 3))
        alphas.append(hit.reshape(size, size))
    return Views(cameras, torch.stack(images), [f"{prefix}_{i}" for i in range(len(cameras))], torch.stack(alphas))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("toy") / "sphere"
    write_blender_split(root, "initial", sphere_views(half_hemisphere_poses(3), "i"))
    write_blender_split(root, "train", sphere_views(sample_uniform_poses(8, torch.Generator().manual_seed(0)), "r"))
    write_blender_split(root, "test", sphere_views(sample_uniform_poses(4, torch.Generator().manual_seed(1)), "t"))
    return root
