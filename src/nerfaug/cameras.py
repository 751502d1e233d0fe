"""Pinhole cameras (OpenGL convention) and batched ray generation.

A camera looks down its local -z axis with +y up and +x right; pixel (0, 0) is the top-left
corner of the image, and the ray of pixel (i, j) passes through its centre (i + 0.5, j + 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class Cameras:
    """A batch of pinhole cameras that share one image size.

    Attributes:
        camera_to_world: Tensor with shape (n_cameras, 4, 4), OpenGL convention.
        fx, fy, cx, cy: Tensors with shape (n_cameras,), in pixels.
        width, height: image size in pixels, the same for every camera.
    """

    camera_to_world: Tensor
    fx: Tensor
    fy: Tensor
    cx: Tensor
    cy: Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        c2w = torch.as_tensor(self.camera_to_world, dtype=torch.float32)
        if c2w.ndim == 2:
            c2w = c2w[None]
        if c2w.shape[-2:] != (4, 4):
            raise ValueError(f"camera_to_world must have shape (n, 4, 4), got {tuple(c2w.shape)}")
        self.camera_to_world = c2w
        n = c2w.shape[0]
        for name in ("fx", "fy", "cx", "cy"):
            value = torch.as_tensor(getattr(self, name), dtype=torch.float32).reshape(-1)
            if value.numel() == 1:
                value = value.expand(n).clone()
            if value.shape != (n,):
                raise ValueError(f"{name} must have {n} entries, got {value.numel()}")
            setattr(self, name, value)
        self.width, self.height = int(self.width), int(self.height)

    @classmethod
    def from_fov(cls, camera_to_world: Tensor, camera_angle_x: float, width: int, height: int) -> Cameras:
        """Cameras from a horizontal field of view (NeRF-synthetic's `camera_angle_x`, radians)."""
        focal = 0.5 * width / math.tan(0.5 * camera_angle_x)
        return cls(camera_to_world, focal, focal, width / 2.0, height / 2.0, width, height)

    def __len__(self) -> int:
        return self.camera_to_world.shape[0]

    def __getitem__(self, index) -> Cameras:
        if isinstance(index, int):
            index = [index]
        return Cameras(
            self.camera_to_world[index],
            self.fx[index],
            self.fy[index],
            self.cx[index],
            self.cy[index],
            self.width,
            self.height,
        )

    @property
    def camera_angle_x(self) -> Tensor:
        """Horizontal field of view per camera, radians. Shape (n_cameras,)."""
        return 2.0 * torch.atan(0.5 * self.width / self.fx)

    @property
    def positions(self) -> Tensor:
        """Camera centres in world space. Shape (n_cameras, 3)."""
        return self.camera_to_world[:, :3, 3]

    @property
    def rotations(self) -> Tensor:
        """Camera-to-world rotations. Shape (n_cameras, 3, 3)."""
        return self.camera_to_world[:, :3, :3]

    def resized(self, width: int, height: int) -> Cameras:
        """The same cameras rendering an image of another size (intrinsics scaled to match)."""
        sx, sy = width / self.width, height / self.height
        return Cameras(
            self.camera_to_world,
            self.fx * sx,
            self.fy * sy,
            self.cx * sx,
            self.cy * sy,
            width,
            height,
        )

    def to(self, device) -> Cameras:
        return Cameras(
            self.camera_to_world.to(device),
            self.fx.to(device),
            self.fy.to(device),
            self.cx.to(device),
            self.cy.to(device),
            self.width,
            self.height,
        )

    @staticmethod
    def cat(cameras: list[Cameras]) -> Cameras:
        """Concatenate batches of cameras of the same image size."""
        sizes = {(c.width, c.height) for c in cameras}
        if len(sizes) != 1:
            raise ValueError(f"cannot concatenate cameras of different image sizes: {sorted(sizes)}")
        width, height = sizes.pop()
        return Cameras(
            torch.cat([c.camera_to_world for c in cameras]),
            torch.cat([c.fx for c in cameras]),
            torch.cat([c.fy for c in cameras]),
            torch.cat([c.cx for c in cameras]),
            torch.cat([c.cy for c in cameras]),
            width,
            height,
        )


def generate_rays(cameras: Cameras, camera_indices: Tensor, pixel_x: Tensor, pixel_y: Tensor) -> tuple[Tensor, Tensor]:
    """Rays through pixel centres for any subset of pixels of any cameras.

    Args:
        cameras: the camera batch.
        camera_indices: Tensor with shape (n_rays,), integer index into `cameras`.
        pixel_x: Tensor with shape (n_rays,), column index (0 = left).
        pixel_y: Tensor with shape (n_rays,), row index (0 = top).

    Returns:
        origins: Tensor with shape (n_rays, 3), world space.
        directions: Tensor with shape (n_rays, 3), unit length, world space.

    Example:
        >>> cams = Cameras.from_fov(torch.eye(4), 0.6911, 100, 100)
        >>> o, d = generate_rays(cams, torch.tensor([0]), torch.tensor([50]), torch.tensor([50]))
        >>> o, d  # pixel (50, 50) is half a pixel right of and below the centre, focal 138.9 px
        (tensor([[0., 0., 0.]]), tensor([[ 0.0036, -0.0036, -1.0000]]))
    """
    device = cameras.camera_to_world.device
    camera_indices = torch.as_tensor(camera_indices, device=device).long()
    x = torch.as_tensor(pixel_x, device=device).float() + 0.5
    y = torch.as_tensor(pixel_y, device=device).float() + 0.5
    local = torch.stack(
        [
            (x - cameras.cx[camera_indices]) / cameras.fx[camera_indices],
            -(y - cameras.cy[camera_indices]) / cameras.fy[camera_indices],
            -torch.ones_like(x),
        ],
        dim=-1,
    )
    c2w = cameras.camera_to_world[camera_indices]
    directions = torch.einsum("rij,rj->ri", c2w[:, :3, :3], local)
    directions = directions / directions.norm(dim=-1, keepdim=True)
    return c2w[:, :3, 3].clone(), directions


def image_rays(cameras: Cameras, index: int) -> tuple[Tensor, Tensor]:
    """All rays of one camera's image in row-major order.

    Returns:
        origins, directions: Tensors with shape (height * width, 3).
    """
    device = cameras.camera_to_world.device
    ys, xs = torch.meshgrid(
        torch.arange(cameras.height, device=device),
        torch.arange(cameras.width, device=device),
        indexing="ij",
    )
    indices = torch.full((cameras.height * cameras.width,), index, device=device)
    return generate_rays(cameras, indices, xs.reshape(-1), ys.reshape(-1))
