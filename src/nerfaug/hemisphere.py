"""Camera poses on the upper hemisphere around an object, and sampling over it.

Angles: `polar` is measured from the world +z axis (0 = straight above, pi/2 = on the ground
plane), `azimuth` counter-clockwise from +x towards +y, both in radians. Every pose looks at
the centre with the camera's +y axis pointing as far "up" (+z) as possible, as in NeRF-synthetic.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

# NeRF-synthetic cameras sit at about this distance from the origin.
BLENDER_RADIUS = 4.031128857175551
BLENDER_CAMERA_ANGLE_X = 0.6911112070083618


def pose_from_angles(azimuth: Tensor, polar: Tensor, radius: float = BLENDER_RADIUS, centre=(0.0, 0.0, 0.0)) -> Tensor:
    """Camera-to-world poses on the hemisphere looking at `centre`.

    Args:
        azimuth: Tensor with shape (n,), radians.
        polar: Tensor with shape (n,), radians from +z.
        radius: distance from the centre.
        centre: point looked at, world space.

    Returns:
        Tensor with shape (n, 4, 4), OpenGL camera-to-world.
    """
    azimuth = torch.as_tensor(azimuth, dtype=torch.float64).reshape(-1)
    polar = torch.as_tensor(polar, dtype=torch.float64).reshape(-1)
    sp, cp = torch.sin(polar), torch.cos(polar)
    sa, ca = torch.sin(azimuth), torch.cos(azimuth)
    backward = torch.stack([sp * ca, sp * sa, cp], dim=-1)  # camera +z, away from the centre
    # Right = up x backward, written out from the azimuth so it stays defined at the pole.
    right = torch.stack([-sa, ca, torch.zeros_like(sa)], dim=-1)
    up = torch.cross(backward, right, dim=-1)
    pose = torch.zeros(azimuth.shape[0], 4, 4, dtype=torch.float64)
    pose[:, :3, 0], pose[:, :3, 1], pose[:, :3, 2] = right, up, backward
    pose[:, :3, 3] = radius * backward + torch.as_tensor(centre, dtype=torch.float64)
    pose[:, 3, 3] = 1.0
    return pose.float()


def angles_from_pose(camera_to_world: Tensor, centre=(0.0, 0.0, 0.0)) -> tuple[Tensor, Tensor, Tensor]:
    """Azimuth, polar angle and radius of camera positions about `centre`.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).

    Returns:
        azimuth in [0, 2 pi), polar in [0, pi], radius: Tensors with shape (n,).
    """
    offset = camera_to_world[:, :3, 3].double() - torch.as_tensor(centre, dtype=torch.float64)
    radius = offset.norm(dim=-1)
    polar = torch.arccos((offset[:, 2] / radius).clamp(-1.0, 1.0))
    azimuth = torch.remainder(torch.atan2(offset[:, 1], offset[:, 0]), 2 * math.pi)
    return azimuth.float(), polar.float(), radius.float()


def sample_uniform_angles(
    n: int,
    generator: torch.Generator | None = None,
    azimuth_range=(0.0, 2 * math.pi),
    polar_range=(0.0, math.pi / 2),
) -> tuple[Tensor, Tensor]:
    """Angles of `n` points uniform in area on a band of the sphere.

    Uniform on the hemisphere means azimuth uniform and cos(polar) uniform (not polar uniform,
    which would crowd the pole).

    Returns:
        azimuth, polar: Tensors with shape (n,).
    """
    u = torch.rand(n, 2, generator=generator, dtype=torch.float64)
    azimuth = azimuth_range[0] + u[:, 0] * (azimuth_range[1] - azimuth_range[0])
    cos_hi, cos_lo = math.cos(polar_range[0]), math.cos(polar_range[1])
    polar = torch.arccos(cos_lo + u[:, 1] * (cos_hi - cos_lo))
    return azimuth.float(), polar.float()


def sample_uniform_poses(
    n: int,
    generator: torch.Generator | None = None,
    radius: float = BLENDER_RADIUS,
    centre=(0.0, 0.0, 0.0),
    azimuth_range=(0.0, 2 * math.pi),
    polar_range=(0.0, math.pi / 2),
) -> Tensor:
    """`n` poses uniform on (a band of) the hemisphere. Shape (n, 4, 4)."""
    azimuth, polar = sample_uniform_angles(n, generator, azimuth_range, polar_range)
    return pose_from_angles(azimuth, polar, radius, centre)


def half_hemisphere_poses(
    n: int,
    azimuth_start: float = math.pi / 2,
    polar_range=(math.radians(20), math.radians(80)),
    radius: float = BLENDER_RADIUS,
    centre=(0.0, 0.0, 0.0),
    azimuth_width: float = math.pi,
) -> Tensor:
    """`n` fixed poses spread over one half of the hemisphere (azimuth in [start, start + width),
    width pi unless given: a captured set that covers a narrower wedge has narrower halves).

    Spread by a golden-angle spiral over the half, so the same `n` always gives the same views
    and they cover the half evenly. Shape (n, 4, 4).
    """
    k = np.arange(n) + 0.5
    frac = k / n
    cos_hi, cos_lo = math.cos(polar_range[0]), math.cos(polar_range[1])
    polar = np.arccos(cos_hi - frac * (cos_hi - cos_lo))
    azimuth = azimuth_start + azimuth_width * np.mod(k * 0.6180339887498949, 1.0)
    return pose_from_angles(torch.from_numpy(azimuth), torch.from_numpy(polar), radius, centre)


def in_azimuth_window(azimuth: Tensor, start: float, width: float = math.pi) -> Tensor:
    """Whether each azimuth lies in [start, start + width) modulo 2 pi. Shape as `azimuth`."""
    return torch.remainder(azimuth - start, 2 * math.pi) < width


def fibonacci_angles(n: int) -> tuple[Tensor, Tensor]:
    """Near-evenly spaced angles over the whole hemisphere (for maps and test splits)."""
    k = np.arange(n) + 0.5
    polar = np.arccos(1.0 - k / n)
    azimuth = np.mod(k * 2 * math.pi * 0.6180339887498949, 2 * math.pi)
    return torch.from_numpy(azimuth).float(), torch.from_numpy(polar).float()
