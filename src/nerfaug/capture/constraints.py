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
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Annotated

import torch
from pydantic import AfterValidator, Field
from torch import Tensor

from nerfaug.capture.requests import RADIUS_RANGE, SCHEMA, Schema, replaced_by, validated
from nerfaug.data.frame import Hemisphere


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


# The ranges a constraint may state: elevation in degrees about the equator, azimuth in degrees
# (an arc may wrap, up to two turns either way), distances in world units.
Elevation = Annotated[float, Field(ge=-90, le=90)]
Azimuth = Annotated[float, Field(ge=-720, le=720)]
Distance = Annotated[float, Field(ge=0, le=RADIUS_RANGE[1] * 1000)]
HalfAngle = Annotated[float, Field(gt=0, lt=180)]
# Keep-out cones one request may state.
MAX_KEEP_OUT = 64


def _ordered(pair: tuple[float, float]) -> tuple[float, float]:
    if pair[0] > pair[1]:
        raise ValueError("low must be <= high")
    return pair


def _pointing(cone: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    if math.hypot(*cone[:3]) < 1e-12:
        raise ValueError("the direction (x, y, z) must not be zero")
    return cone


Cone = Annotated[tuple[float, float, float, HalfAngle], AfterValidator(_pointing)]


@dataclass(kw_only=True)
class ViewConstraints(Schema):
    """Where proposed views may lie (degrees, world units): ranges about the session's hemisphere,
    applied to the hemisphere's candidates or to reachable poses, and keep-out cones."""

    __pydantic_config__ = SCHEMA

    elevation: Annotated[
        Annotated[tuple[Elevation, Elevation], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) degrees above the hemisphere's equator, in [-90, 90]."""
    azimuth: Annotated[
        Annotated[tuple[Azimuth, Azimuth], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) degrees about the hemisphere's up, counter-clockwise, in [-720, 720]; may wrap: 315 405."""
    radius: Annotated[
        Annotated[tuple[Distance, Distance], AfterValidator(_ordered)] | None, replaced_by("any", "LOW HIGH")
    ] = None
    """(low, high) distance from the hemisphere's centre, world units (for reachable poses)."""
    keep_out: Annotated[
        tuple[Cone, ...],
        Field(max_length=MAX_KEEP_OUT),
        replaced_by("no cone", "X Y Z HALF_ANGLE [X Y Z HALF_ANGLE ...]"),
    ] = ()
    """cones to stay out of: a world-frame direction from the centre and a half-angle (0, 180) degrees each."""

    @property
    def empty(self) -> bool:
        """True when nothing is constrained."""
        return self.elevation is None and self.azimuth is None and self.radius is None and not self.keep_out

    def mask(self, camera_to_world: Tensor, hemisphere: Hemisphere) -> Tensor:
        """Which poses satisfy every constraint.

        Args:
            camera_to_world: Tensor with shape (n, 4, 4), world frame.
            hemisphere: the session's hemisphere (centre, radius, up).

        Returns:
            Tensor with shape (n,), bool.
        """
        poses = torch.as_tensor(camera_to_world).reshape(-1, 4, 4)
        keep = torch.ones(poses.shape[0], dtype=torch.bool)
        if poses.shape[0] == 0 or self.empty:
            return keep
        azimuth, polar, radius = hemisphere.angles(poses)
        if self.elevation is not None:
            keep &= angle_range_mask(90.0 - torch.rad2deg(polar.double()), *self.elevation)
        if self.azimuth is not None:
            keep &= azimuth_mask(torch.rad2deg(azimuth.double()), *self.azimuth)
        if self.radius is not None:
            keep &= angle_range_mask(radius.double(), *self.radius)
        if self.keep_out:
            cones = torch.tensor(self.keep_out, dtype=torch.float64)
            keep &= keep_out_mask(
                poses[:, :3, 3], torch.tensor(hemisphere.centre, dtype=torch.float64), cones[:, :3], cones[:, 3]
            )
        return keep

    def to_dict(self) -> dict:
        """JSON-ready: lists for the ranges and cones (recorded with a proposal)."""
        ranges = {k: None if v is None else list(v) for k, v in asdict(self).items() if k != "keep_out"}
        return {**ranges, "keep_out": [list(c) for c in self.keep_out]}

    @classmethod
    def from_dict(cls, data: dict | None) -> ViewConstraints:
        """The inverse of `to_dict`, checked (RequestError naming the field otherwise)."""
        return validated(cls, data or {})


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
    kept = torch.nonzero(constraints.mask(camera_to_world, hemisphere)).reshape(-1)
    if kept.numel() < n:
        raise TooFewCandidates(
            f"constraints leave {kept.numel()} of {total} candidates; {n} asked (widen the ranges, "
            "give more candidates, or ask for fewer views)"
        )
    return kept
