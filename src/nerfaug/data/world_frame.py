"""The hemisphere candidate views live on, and the engine frame the NeRF is trained in.

Poses given to and returned by a session are in the dataset's world frame (OpenGL
camera-to-world, as in the Blender and nerfstudio formats). The NeRF is trained in an *engine
frame*: the hemisphere's centre at the origin, its `up` along +z, and its radius scaled to
`ENGINE_RADIUS` (NeRF-synthetic's 4.03), so that the engine's scene bounds (near 2, far 6, a box
of half-size 1.5) fit any object-centred capture, whatever its units. For NeRF-synthetic data
the two frames coincide (up to the estimate of the centre and radius).

The hemisphere is where candidate views live (the paper's Sec. III-C): the upper half, relative
to `up`, of the sphere of `radius` about `centre`. Both can be given or estimated from the
cameras (`estimate_hemisphere`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_RADIUS, angles_from_pose

ENGINE_RADIUS = BLENDER_RADIUS


class TooFewCameras(ValueError):
    """Fewer cameras than `estimate_centre` needs (2); `count` is how many there are."""

    def __init__(self, count: int):
        self.count = count
        super().__init__(
            f"estimating the hemisphere's centre needs at least 2 cameras, got {count}: capture at least 2 views, "
            "or give the centre and radius"
        )


def estimate_centre(camera_to_world: Tensor) -> Tensor:
    """The point closest, in least squares, to every camera's optical axis.

    Minimises sum_i || (I - d_i d_i^T) (x - o_i) ||^2 over x, for camera centres o_i and viewing
    directions d_i (each camera's -z axis): the point the cameras look at.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4), n >= 2, OpenGL convention.

    Returns:
        Tensor with shape (3,), float64, world space.

    Raises:
        TooFewCameras: fewer than two cameras.
        ValueError: optical axes (nearly) parallel, so no single point is looked at.

    Example:
        >>> from nerfaug.hemisphere import half_hemisphere_poses
        >>> estimate_centre(half_hemisphere_poses(8, centre=(1.0, 2.0, 0.5)))
        tensor([1.0000, 2.0000, 0.5000], dtype=torch.float64)
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    if poses.shape[0] < 2:
        raise TooFewCameras(poses.shape[0])
    origins = poses[:, :3, 3]
    directions = -poses[:, :3, 2]
    directions = directions / directions.norm(dim=-1, keepdim=True)
    projectors = torch.eye(3, dtype=torch.float64) - directions[:, :, None] * directions[:, None, :]
    a = projectors.sum(0)
    b = (projectors @ origins[:, :, None]).sum(0)[:, 0]
    eigenvalues = torch.linalg.eigvalsh(a)
    # An eigenvalue near 0 means a direction along which every axis runs: no unique closest point.
    if eigenvalues[0] < 1e-6 * poses.shape[0]:
        raise ValueError(
            "the cameras' optical axes are (nearly) parallel, so they do not look at one point; "
            "give the hemisphere's centre and radius explicitly"
        )
    return torch.linalg.solve(a, b)


def estimate_up(camera_to_world: Tensor) -> Tensor:
    """The mean of the cameras' +y (up) axes, normalised: the world's up for captures taken upright.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).

    Returns:
        Tensor with shape (3,), float64, unit length.
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    up = poses[:, :3, 1].mean(0)
    if up.norm() < 1e-6:
        raise ValueError("the cameras' up axes cancel out; give the up direction explicitly")
    return up / up.norm()


def pole_tilt_degrees(camera_to_world: Tensor, up) -> float | None:
    """Degrees between the pole `up` (3,) and the cameras' mean up axis (`estimate_up`): near 0
    for a capture taken upright in a world whose up is `up`; None when the cameras' up axes cancel.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).
        up: the pole direction, world space, any length.
    """
    try:
        mean_up = estimate_up(camera_to_world)
    except ValueError:
        return None
    pole = torch.as_tensor(up, dtype=torch.float64)
    cosine = float(mean_up @ (pole / pole.norm()))
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


# A pole farther than this from the cameras' mean up axis leaves the candidate views on a tilted
# hemisphere, much of it below the capture's horizon.
TILTED_POLE_DEGREES = 60.0


def pole_is_estimated(camera_to_world: Tensor, z_up: bool | None) -> bool:
    """Whether a capture's pole, when none is given, is the cameras' mean up axis (`estimate_up`)
    rather than world +z: where the dataset's format records no up direction (`z_up` False: LLFF,
    IDR/DTU), and where it may or may not (`z_up` None: nerfstudio) when +z lies more than
    `TILTED_POLE_DEGREES` from the cameras' mean up axis. Never where the cameras' up axes cancel
    out (no up to estimate: +z stays).

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).
        z_up: the format's `Format.z_up`.

    Example:
        >>> from nerfaug.hemisphere import half_hemisphere_poses
        >>> upright = half_hemisphere_poses(6)
        >>> pole_is_estimated(upright, True), pole_is_estimated(upright, None), pole_is_estimated(upright, False)
        (False, False, True)
    """
    tilt = pole_tilt_degrees(camera_to_world, (0.0, 0.0, 1.0))
    if tilt is None or z_up:
        return False
    return z_up is False or tilt > TILTED_POLE_DEGREES


def plain_number(value: float, decimals: int = 4) -> str:
    """`value` rounded to `decimals` places as a person writes it: no "-0", no exponent for the
    float noise of a zero (6.95e-08 -> "0").

    Example:
        >>> plain_number(-0.0), plain_number(6.95e-08), plain_number(2.5), plain_number(-1.23456)
        ('0', '0', '2.5', '-1.2346')
    """
    rounded = round(float(value), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0
    return f"{rounded:.{decimals}f}".rstrip("0").rstrip(".")


@dataclass(frozen=True)
class Hemisphere:
    """The upper half, relative to `up`, of the sphere of `radius` about `centre` (world frame).

    It also defines the engine frame the NeRF is trained in: centre at the origin, `up` along +z,
    world x (or y, if `up` is close to x) projected onto the horizontal plane along +x, and
    lengths divided by `radius / ENGINE_RADIUS`.

    Attributes:
        centre: the point looked at, world space.
        radius: distance of the candidate cameras from the centre, world units.
        up: the hemisphere's pole direction (unit length), world space.
    """

    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = ENGINE_RADIUS
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        centre = tuple(float(c) for c in np.asarray(self.centre, dtype=np.float64).reshape(-1))
        up = np.asarray(self.up, dtype=np.float64).reshape(-1)
        if len(centre) != 3 or up.shape != (3,):
            raise ValueError(f"centre and up must be 3-vectors, got {self.centre} and {self.up}")
        if not all(math.isfinite(c) for c in centre):
            raise ValueError(f"the hemisphere's centre must be finite, got {self.centre}")
        if not (math.isfinite(float(self.radius)) and float(self.radius) > 0):
            raise ValueError(f"the hemisphere's radius must be a positive number, got {self.radius}")
        if not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
            raise ValueError(f"up must be a non-zero direction, got {self.up}")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "up", tuple(float(u) for u in up / np.linalg.norm(up)))

    def __str__(self) -> str:
        """As a person reads it: "centre (0, 0, 0), radius 4, up (0, 0, 1)" (4 decimals, no -0)."""

        def plain(values) -> str:
            return "(" + ", ".join(plain_number(v) for v in values) + ")"

        return f"centre {plain(self.centre)}, radius {plain_number(self.radius)}, up {plain(self.up)}"

    @property
    def scale(self) -> float:
        """World units per engine unit."""
        return self.radius / ENGINE_RADIUS

    def rotation(self) -> Tensor:
        """Engine-to-world rotation, float64 (3, 3); its columns are the engine axes in the world."""
        up = torch.tensor(self.up, dtype=torch.float64)
        axis = [1.0, 0.0, 0.0] if abs(float(up[0])) < 0.9 else [0.0, 1.0, 0.0]
        reference = torch.tensor(axis, dtype=torch.float64)
        x = reference - (reference @ up) * up
        x = x / x.norm()
        return torch.stack([x, torch.linalg.cross(up, x), up], dim=1)

    def to_engine(self, camera_to_world: Tensor) -> Tensor:
        """World-frame poses (n, 4, 4) in the engine frame, float32 (n, 4, 4)."""
        poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
        rotation = self.rotation()
        out = poses.clone()
        out[:, :3, :3] = rotation.T @ poses[:, :3, :3]
        offset = poses[:, :3, 3] - torch.tensor(self.centre, dtype=torch.float64)
        out[:, :3, 3] = offset @ rotation / self.scale
        return out.float()

    def cameras_to_engine(self, cameras: Cameras) -> Cameras:
        """World-frame `cameras` in the engine frame: their poses moved (`to_engine`), their
        intrinsics and image size kept."""
        engine = self.to_engine(cameras.camera_to_world)
        return Cameras(engine, cameras.fx, cameras.fy, cameras.cx, cameras.cy, cameras.width, cameras.height)

    def to_world(self, camera_to_world: Tensor) -> Tensor:
        """Engine-frame poses (n, 4, 4) in the world frame, float32 (n, 4, 4)."""
        poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
        rotation = self.rotation()
        out = poses.clone()
        out[:, :3, :3] = rotation @ poses[:, :3, :3]
        out[:, :3, 3] = torch.tensor(self.centre, dtype=torch.float64) + self.scale * poses[:, :3, 3] @ rotation.T
        return out.float()

    def angles(self, camera_to_world: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Azimuth and polar angle (radians, about `up`) and distance (world units) of world poses.

        Returns:
            azimuth, polar, radius: Tensors with shape (n,).
        """
        azimuth, polar, radius = angles_from_pose(self.to_engine(camera_to_world))
        return azimuth, polar, radius * self.scale

    def to_dict(self) -> dict:
        return {"centre": list(self.centre), "radius": self.radius, "up": list(self.up)}

    @classmethod
    def from_dict(cls, data: dict) -> Hemisphere:
        return cls(tuple(data["centre"]), float(data["radius"]), tuple(data["up"]))


# A given radius farther than this factor from the cameras' distance to the centre is refused:
# the engine frame scales the scene by it, and the cameras would leave the NeRF's box.
RADIUS_FACTOR = 1000.0


def estimate_hemisphere(
    camera_to_world: Tensor, centre=None, radius: float | None = None, up=(0.0, 0.0, 1.0)
) -> Hemisphere:
    """The hemisphere the cameras sit on: what is not given is estimated from them.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4), the existing cameras.
        centre: the point looked at; None for `estimate_centre` (the point closest to all
            optical axes).
        radius: None for the mean distance of the cameras from the centre.
        up: the pole direction; "estimate" for `estimate_up` (the mean camera up axis).

    Returns:
        Hemisphere.
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    if isinstance(up, str):
        if up != "estimate":
            raise ValueError(f"up must be a 3-vector or 'estimate', got {up!r}")
        up = estimate_up(poses)
    centre = estimate_centre(poses) if centre is None else torch.as_tensor(centre, dtype=torch.float64)
    distance = float((poses[:, :3, 3] - centre).norm(dim=-1).mean())
    if radius is None:
        radius = distance
    elif distance > 0 and not distance / RADIUS_FACTOR <= float(radius) <= distance * RADIUS_FACTOR:
        raise ValueError(
            f"radius {float(radius):g}: the cameras lie {distance:.4g} from the centre on average; give a radius "
            f"within {RADIUS_FACTOR:g}x of that (or none: their mean distance)"
        )
    return Hemisphere(tuple(centre.tolist()), radius, tuple(torch.as_tensor(up, dtype=torch.float64).tolist()))
