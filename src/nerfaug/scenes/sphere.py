"""An analytic scene made without Blender: a sphere of radius 0.8 at the origin, coloured by its
normal, on white. The toy scene of the GPU study's CPU mode (`benchmarks/gpu_study.py`) and of
the tests: exact images, rendered in a moment, no bpy and no download."""

from __future__ import annotations

import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data.views import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X

SPHERE_RADIUS = 0.8


def sphere_views(poses: torch.Tensor, prefix: str, size: int = 24) -> Views:
    """The sphere seen from camera-to-world `poses` (n, 4, 4), `size` x `size` pixels with
    NeRF-synthetic's field of view: images (n, size, size, 3) in [0, 1] with their alphas
    (n, size, size), named "<prefix>_<i>"."""
    cameras = Cameras.from_fov(poses.float(), BLENDER_CAMERA_ANGLE_X, size, size)
    images, alphas = [], []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        # The nearer root of |o + t d| = r, for unit d: t = -b - sqrt(b^2 - (|o|^2 - r^2)).
        b = (origins * directions).sum(-1)
        disc = b**2 - ((origins**2).sum(-1) - SPHERE_RADIUS**2)
        normal = torch.nn.functional.normalize(origins + (-b - disc.clamp_min(0).sqrt())[:, None] * directions, dim=-1)
        hit = (disc > 0).float()
        images.append((hit[:, None] * (0.5 + 0.5 * normal) + (1 - hit[:, None])).reshape(size, size, 3))
        alphas.append(hit.reshape(size, size))
    return Views(cameras, torch.stack(images), [f"{prefix}_{i}" for i in range(len(cameras))], torch.stack(alphas))
