"""Uncertainty of every pixel of a view: the render, its depth, the ray entropy image and FisherRF's
per-pixel score (what the per-view scores of `entropy` and `fisher` average or sum).

- The entropy image holds `ray_entropy` of each pixel's ray (bits); its mean over a view rendered
  at `resolution` pixels across is the view's `mean_view_entropy` at that resolution.
- The FisherRF image holds each pixel's expected information gain,
  sum_k H_pixel[k] / (H_train[k] + lambda), with H_pixel the pixel's own Fisher diagonal (the sum
  over colour channels of (d c / d theta)^2, exact: one ray per probe). Its sum over the image is
  the view's FisherRF score over all its pixels (`fisherrf_scores` of `fisher_views` at full
  resolution). Three backward passes per pixel: render it small (tens of pixels across).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.uncertainty.entropy import ray_entropy
from nerfaug.uncertainty.fisher import FISHER_LAMBDA, fisher_diagonal_groups
from nerfaug.uncertainty.rays import render_no_grad, views_rays


@torch.no_grad()
def view_images(
    model: nn.Module,
    cameras: Cameras,
    index: int = 0,
    background: Tensor | None = None,
    mode: str = "escape",
    chunk: int = 4096,
) -> dict[str, Tensor]:
    """Render view `index` of `cameras` with its per-pixel ray entropy (eval mode, no gradients).

    Args:
        model: a module with the `NerfModel` interface.
        cameras: the views; their size is the images' size.
        index: which view.
        background: Tensor with shape (3,), the colour behind the scene; None for the model's own.
        mode: the entropy's mode (`ray_entropy`).
        chunk: rays per forward pass.

    Returns:
        {"rgb": (H, W, 3) in [0, 1], "depth": (H, W) (the model's units), "accumulation": (H, W),
        "entropy": (H, W) bits}, on the CPU.
    """
    origins, directions = views_rays(cameras, [index])
    if hasattr(model, "render_rays"):
        device = next(model.parameters()).device
        out = model.render_rays(origins.to(device), directions.to(device), background=background, chunk=chunk)
    else:
        out = render_no_grad(model, origins, directions, chunk)
    shape = (cameras.height, cameras.width)
    return {
        "rgb": out.rgb.reshape(*shape, 3).cpu(),
        "depth": out.depth.reshape(shape).cpu(),
        "accumulation": out.accumulation.reshape(shape).cpu(),
        "entropy": ray_entropy(out.weights, mode).reshape(shape).cpu(),
    }


def fisher_pixel_scores(
    model: nn.Module,
    cameras: Cameras,
    h_train: Tensor,
    index: int = 0,
    lam: float = FISHER_LAMBDA,
    background: Tensor | None = None,
    batch: int = 64,
) -> Tensor:
    """FisherRF's expected information gain of each pixel of view `index` (see the module docstring).

    Args:
        model: a module with the `NerfModel` interface.
        cameras: the views; their size is the image's size.
        h_train: Tensor with shape (P,), the Fisher diagonal of the training views
            (`fisher_diagonal` over their pixels).
        index: which view.
        lam: FisherRF's lambda.
        background: Tensor with shape (3,), or None for the model's own.
        batch: pixels whose diagonals are held at once (batch x P floats).

    Returns:
        Tensor with shape (H, W), >= 0, on the CPU.
    """
    origins, directions = views_rays(cameras, [index])
    inverse = 1.0 / (h_train + lam)
    # A fixed generator: the probes' signs square away (one ray per probe), and the global RNG is left alone.
    generator = torch.Generator().manual_seed(0)
    scores = []
    for start in range(0, origins.shape[0], batch):
        o, d = origins[start : start + batch], directions[start : start + batch]
        n = o.shape[0]
        h = fisher_diagonal_groups(
            model, o, d, torch.arange(n), n, "random-sign", 1, generator, chunk=1, background=background
        )
        scores.append((h @ inverse.to(h.device)).cpu())
    return torch.cat(scores).reshape(cameras.height, cameras.width)
