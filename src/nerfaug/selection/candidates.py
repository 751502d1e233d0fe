"""Candidate views to choose from: poses uniform on the hemisphere, or a given pool of cameras,
without the views already in the training set."""

from __future__ import annotations

import torch
from torch import Tensor

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import sample_uniform_poses
from nerfaug.uncertainty.so3 import so3_geodesic_sq

N_CANDIDATES = 500


def with_poses(template: Cameras, poses: Tensor) -> Cameras:
    """Cameras at `poses` (n, 4, 4) with the intrinsics of `template`'s first camera."""
    first = template[0]
    return Cameras(
        poses,
        float(first.fx[0]),
        float(first.fy[0]),
        float(first.cx[0]),
        float(first.cy[0]),
        template.width,
        template.height,
    )


def matching_poses(
    poses: Tensor, reference: Tensor, position_tolerance: float = 1e-3, angle_tolerance: float = 1e-3
) -> Tensor:
    """Which poses coincide with some reference pose (same centre and orientation, within tolerance).

    Args:
        poses: Tensor with shape (n, 4, 4), camera-to-world.
        reference: Tensor with shape (m, 4, 4), camera-to-world.
        position_tolerance: largest distance between camera centres, world units.
        angle_tolerance: largest rotation angle between the orientations, radians.

    Returns:
        Bool tensor with shape (n,).
    """
    if reference.shape[0] == 0 or poses.shape[0] == 0:
        return torch.zeros(poses.shape[0], dtype=torch.bool)
    poses, reference = poses.double(), reference.double()
    close = torch.cdist(poses[:, :3, 3], reference[:, :3, 3]) <= position_tolerance
    angles_sq = so3_geodesic_sq(reference[None, :, :3, :3], poses[:, None, :3, :3])
    return (close & (angles_sq <= angle_tolerance**2)).any(dim=1)


def pool_candidates(
    pool: Cameras,
    training: Cameras | None = None,
    position_tolerance: float = 1e-3,
    angle_tolerance: float = 1e-3,
) -> tuple[Cameras, Tensor]:
    """The cameras of a pool (e.g. a dataset's train split) that are not training views.

    Returns:
        candidates: the remaining cameras, in pool order.
        indices: Tensor with shape (n_candidates,), their indices into `pool`.
    """
    keep = torch.ones(len(pool), dtype=torch.bool)
    if training is not None:
        keep = ~matching_poses(
            pool.camera_to_world.cpu(), training.camera_to_world.cpu(), position_tolerance, angle_tolerance
        )
    indices = torch.nonzero(keep).reshape(-1)
    return pool[indices.tolist()], indices


def hemisphere_candidates(
    template: Cameras,
    n: int = N_CANDIDATES,
    generator: torch.Generator | None = None,
    radius: float | None = None,
    centre=(0.0, 0.0, 0.0),
    training: Cameras | None = None,
    position_tolerance: float = 1e-3,
    angle_tolerance: float = 1e-3,
) -> Cameras:
    """`n` poses uniform in area on the upper hemisphere, looking at `centre`, minus training views.

    Args:
        template: cameras whose first entry gives the intrinsics and image size of the candidates
            and, unless `radius` is given, whose mean distance from `centre` gives the radius.
        n: number of poses drawn (fewer are returned if some coincide with training views).
        generator: random source; the same seed gives the same candidates.
        radius: distance of the candidates from `centre`.
        centre: point looked at, world space.
        training: training cameras to leave out.

    Returns:
        Cameras with the template's intrinsics.
    """
    if radius is None:
        offsets = template.positions - torch.as_tensor(centre, dtype=torch.float32)
        radius = float(offsets.norm(dim=-1).mean())
    poses = sample_uniform_poses(n, generator, radius=radius, centre=centre)
    if training is not None:
        poses = poses[~matching_poses(poses, training.camera_to_world.cpu(), position_tolerance, angle_tolerance)]
    return with_poses(template, poses)
