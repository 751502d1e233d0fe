"""Rays of candidate views at reduced resolution, and rendering them without gradients.

Every estimator scores a view from a low-resolution rendering of it; this module builds those rays
for many views at once and renders them through any model with the `NerfModel` interface
(`forward(origins, directions, background=None) -> RenderOutput`), using, when the model has them,
`render_rays(origins, directions, chunk=...) -> RenderOutput` (no grad, chunked) and
`render_weights_only(origins, directions, chunk=...) -> Tensor (n_rays, n_samples)` (the weights
alone: the entropy needs no colour, and skipping the colour network about halves the cost).
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras, generate_rays
from nerfaug.nerf.volrend import RenderOutput


def reduced_cameras(cameras: Cameras, resolution: int) -> Cameras:
    """The cameras rendering `resolution` pixels across, keeping the aspect ratio.

    Args:
        cameras: n cameras.
        resolution: width in pixels of the reduced image (the height follows the aspect ratio).
    """
    if resolution < 1:
        raise ValueError(f"resolution must be at least 1 pixel, got {resolution}")
    height = max(1, round(resolution * cameras.height / cameras.width))
    return cameras.resized(resolution, height)


def views_rays(cameras: Cameras, indices: Tensor | list[int]) -> tuple[Tensor, Tensor]:
    """All rays of the views `indices`, view after view, each row-major.

    Args:
        cameras: camera batch.
        indices: which cameras, length n.

    Returns:
        origins, directions: Tensors with shape (n * height * width, 3).
    """
    device = cameras.camera_to_world.device
    indices = torch.as_tensor(indices, device=device).long().reshape(-1)
    ys, xs = torch.meshgrid(
        torch.arange(cameras.height, device=device),
        torch.arange(cameras.width, device=device),
        indexing="ij",
    )
    n_pixels = cameras.height * cameras.width
    return generate_rays(
        cameras,
        indices.repeat_interleave(n_pixels),
        xs.reshape(-1).repeat(len(indices)),
        ys.reshape(-1).repeat(len(indices)),
    )


def view_batches(n_views: int, rays_per_view: int, chunk: int) -> Iterator[list[int]]:
    """Consecutive groups of views with about `chunk` rays per group (at least one view)."""
    per_batch = max(1, chunk // max(1, rays_per_view))
    for start in range(0, n_views, per_batch):
        yield list(range(start, min(n_views, start + per_batch)))


def model_device(model: nn.Module) -> torch.device:
    """Where the model's parameters live (CPU for a model without parameters)."""
    for parameter in model.parameters():
        return parameter.device
    return torch.device("cpu")


@torch.no_grad()
def render_weights_no_grad(model: nn.Module, origins: Tensor, directions: Tensor, chunk: int = 4096) -> Tensor:
    """Volume-rendering weights of rays in eval mode without gradients. Shape (n_rays, n_samples).

    Through `model.render_weights_only` when the model has it, else `render_no_grad(...).weights`."""
    if hasattr(model, "render_weights_only"):
        device = model_device(model)
        return model.render_weights_only(origins.to(device), directions.to(device), chunk=chunk)
    return render_no_grad(model, origins, directions, chunk).weights


@torch.no_grad()
def render_no_grad(model: nn.Module, origins: Tensor, directions: Tensor, chunk: int = 4096) -> RenderOutput:
    """Render rays in eval mode without gradients, through `model.render_rays` when it has one.

    Args:
        model: a module with `forward(origins, directions, background=None) -> RenderOutput`.
        origins, directions: Tensors with shape (n_rays, 3).
        chunk: rays per forward pass.

    Returns:
        RenderOutput for the n_rays rays (no extras).
    """
    device = model_device(model)
    origins, directions = origins.to(device), directions.to(device)
    if hasattr(model, "render_rays"):
        return model.render_rays(origins, directions, chunk=chunk)
    was_training = model.training
    model.eval()
    try:
        parts = [
            model(origins[i : i + chunk], directions[i : i + chunk]).detach() for i in range(0, origins.shape[0], chunk)
        ]
    finally:
        model.train(was_training)
    return RenderOutput.cat(parts)
