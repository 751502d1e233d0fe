"""Where a camera may go: elevation, azimuth and radius ranges about the session's hemisphere, and
keep-out cones, applied to a pool of candidate poses (the hemisphere's, or a robot's reachable set).

Angles here are in degrees, as a user states a workspace: elevation is measured up from the
hemisphere's equator (90 - polar; 90 at the pole, negative below the equator), azimuth about the
hemisphere's `up` from its x axis (`Hemisphere.angles`; world +x for a z-up world), radius is the
camera's distance from the hemisphere's centre in world units. A keep-out cone is a direction from
the centre (world frame) and a half-angle: cameras whose position lies within the cone are left out
(e.g. where the robot's base or a wall is).

Hemisphere candidates all lie at the hemisphere's radius, so a radius range keeps all or none of
them; it is meant for a list of reachable poses.

The constraints as asked, checked, are `ViewConstraints` (`nerfaug.capture.proposal_request`);
here they are applied (`constraints_mask`, `constrained_indices`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from nerfaug.capture.proposal_request import ViewConstraints
from nerfaug.data.world_frame import Hemisphere


def angle_range_mask(values: Tensor, low: float, high: float) -> Tensor:
    """Which angles lie in [low, high] (degrees), with no wrap-around: for elevation.

    Args:
        values: Tensor with shape (n,), degrees.

    Returns:
        Tensor with shape (n,), bool.

    Example:
        >>> angle_range_mask(torch.tensor([10.0, 45.0, 80.0]), 20.0, 60.0)
        tensor([False,  True, False])
    """
    return (values >= low) & (values <= high)


def azimuth_mask(azimuth: Tensor, low: float, high: float) -> Tensor:
    """Which azimuths lie on the arc from `low` counter-clockwise to `high` (degrees), wrapping
    through 360: (300, 420) and (-60, 60) are the same 120-degree arc about 0. An arc of 360
    degrees or more keeps every azimuth.

    Args:
        azimuth: Tensor with shape (n,), degrees (any range; taken modulo 360).
        low, high: the arc's ends, high >= low.

    Returns:
        Tensor with shape (n,), bool.

    Example:
        >>> azimuth_mask(torch.tensor([0.0, 50.0, 90.0, 330.0]), -60.0, 60.0)
        tensor([ True,  True, False,  True])
    """
    if high - low >= 360.0:
        return torch.ones_like(azimuth, dtype=torch.bool)
    offset = torch.remainder(azimuth.double() - low, 360.0)
    return offset <= (high - low) + 1e-9


def keep_out_mask(positions: Tensor, centre: Tensor, axes: Tensor, half_angles: Tensor) -> Tensor:
    """Which positions lie outside every keep-out cone with its apex at `centre`.

    A position on a cone's boundary (angle to the axis equal to the half-angle) is outside it.

    Args:
        positions: Tensor with shape (n, 3), camera centres, world frame.
        centre: Tensor with shape (3,), the cones' common apex.
        axes: Tensor with shape (k, 3), the cones' directions (any non-zero length).
        half_angles: Tensor with shape (k,), degrees.

    Returns:
        Tensor with shape (n,), bool: True where the position is in no cone.

    Example:
        >>> keep_out_mask(torch.tensor([[1.0, 0, 0], [0, 1.0, 0]]), torch.zeros(3),
        ...               torch.tensor([[1.0, 0.1, 0]]), torch.tensor([10.0]))
        tensor([False,  True])
    """
    positions = positions.double().reshape(-1, 3)
    if axes.numel() == 0:
        return torch.ones(positions.shape[0], dtype=torch.bool)
    offsets = positions - centre.double().reshape(1, 3)
    unit = offsets / offsets.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    axes = axes.double().reshape(-1, 3)
    axes = axes / axes.norm(dim=-1, keepdim=True)
    cosines = (unit @ axes.T).clamp(-1.0, 1.0)  # (n, k)
    angles = torch.rad2deg(torch.arccos(cosines))
    inside = angles < half_angles.double().reshape(1, -1) - 1e-9
    return ~inside.any(dim=-1)


def constraints_mask(constraints: ViewConstraints, camera_to_world: Tensor, hemisphere: Hemisphere) -> Tensor:
    """Which poses satisfy every constraint of `constraints`.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4), world frame.
        hemisphere: the session's hemisphere (centre, radius, up).

    Returns:
        Tensor with shape (n,), bool.
    """
    poses = torch.as_tensor(camera_to_world).reshape(-1, 4, 4)
    keep = torch.ones(poses.shape[0], dtype=torch.bool)
    if poses.shape[0] == 0 or constraints.empty:
        return keep
    azimuth, polar, radius = hemisphere.angles(poses)
    if constraints.elevation is not None:
        keep &= angle_range_mask(90.0 - torch.rad2deg(polar.double()), *constraints.elevation)
    if constraints.azimuth is not None:
        keep &= azimuth_mask(torch.rad2deg(azimuth.double()), *constraints.azimuth)
    if constraints.radius is not None:
        keep &= angle_range_mask(radius.double(), *constraints.radius)
    if constraints.keep_out:
        cones = torch.tensor(constraints.keep_out, dtype=torch.float64)
        keep &= keep_out_mask(
            poses[:, :3, 3], torch.tensor(hemisphere.centre, dtype=torch.float64), cones[:, :3], cones[:, 3]
        )
    return keep


class TooFewCandidates(ValueError):
    """Constraints left fewer candidates than views asked for; the message gives both numbers."""


def constrained_indices(
    camera_to_world: Tensor, hemisphere: Hemisphere, constraints: ViewConstraints | None, n: int
) -> Tensor:
    """Indices of the poses within `constraints`, at least `n` of them.

    Args:
        camera_to_world: Tensor with shape (C, 4, 4), the candidate pool, world frame.
        hemisphere: the session's hemisphere.
        constraints: checked (`ViewConstraints.checked`); None keeps every pose.
        n: views asked for.

    Returns:
        Tensor with shape (C',), int64, C' >= n, increasing.

    Raises:
        TooFewCandidates: "constraints leave 4 of 300 candidates; 6 asked".
    """
    total = int(torch.as_tensor(camera_to_world).reshape(-1, 4, 4).shape[0])
    if constraints is None or constraints.empty:
        return torch.arange(total)
    kept = torch.nonzero(constraints_mask(constraints, camera_to_world, hemisphere)).reshape(-1)
    if kept.numel() < n:
        raise TooFewCandidates(
            f"constraints leave {kept.numel()} of {total} candidates; {n} asked (widen the ranges, "
            "give more candidates, or ask for fewer views)"
        )
    return kept
