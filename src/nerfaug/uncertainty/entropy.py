"""Entropy of the volume-rendering weights along rays: the paper's in-distribution term H
(Sec. III-B, Eq. 2, after Lee et al.'s "spatial entropy").

The weights w_i = T_i (1 - exp(-sigma_i delta_i)) of a ray are the probabilities that it
terminates in interval i; they sum to the ray's opacity, which is below 1 where the ray sees
background. Modes of `ray_entropy`, all in bits:

- "escape" (default): complete the distribution with one more outcome, "the ray escapes",
  of mass 1 - sum_i w_i. This is the distribution volume rendering itself defines (the background
  colour is composited with exactly that mass), so it needs no rescaling: a ray that confidently
  sees empty space has entropy 0, a ray that confidently hits one surface has entropy 0, and a ray
  that is unsure whether and where it hits has high entropy. Range [0, log2(n_samples + 1)].
- "renormalise": p = w / sum(w), the termination depth given that the ray terminates. A ray with
  tiny, spread-out weights (background seen through faint floaters) scores as high as a truly
  ambiguous one, which is why it is not the default. Rays with all-zero weights score 0.
- "raw": -sum_i w_i log2 w_i on the weights as they are (Eq. 2 read literally, no completion).
- "authors": the authors' code: p = w / max(w) with the maximum over all rays given (pass one
  view's rays), 1e-9 added inside the log when any p is 0, times 10. `view_entropy` in this mode
  also cubes the per-view means and min-max normalises them over the views, as that code does.

Zero weights contribute 0 (0 log 0 = 0) with a zero gradient, so neither values nor gradients
are ever NaN or infinite.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.registry import check_name, unknown
from nerfaug.uncertainty.choices import ENTROPY_MODES
from nerfaug.uncertainty.rays import reduced_cameras, render_weights_no_grad, view_batches, views_rays

# The authors' code: epsilon inside the log when some probability is 0, and the scale factor.
AUTHORS_LOG_EPS = 1e-9
AUTHORS_SCALE = 10.0


def _neg_p_log2_p(p: Tensor) -> Tensor:
    """-p log2 p elementwise with 0 at p <= 0, and a zero (not infinite) gradient there."""
    if not (p.requires_grad and torch.is_grad_enabled()):
        # entr is one fused kernel (-p ln p, 0 at 0); its gradient at 0 would be infinite.
        return torch.special.entr(p.clamp_min(0.0)) / math.log(2.0)
    positive = p > 0
    safe = torch.where(positive, p, torch.ones_like(p))
    return torch.where(positive, -p * torch.log2(safe), torch.zeros_like(p))


def _authors_entropy(weights: Tensor) -> Tensor:
    """(..., n_rays, n_samples) -> (..., n_rays): the authors' entropy, max over each ray group."""
    scale = weights.detach().amax(dim=(-2, -1), keepdim=True)
    p = weights / torch.where(scale > 0, scale, torch.ones_like(scale))
    any_zero = (p <= 0).flatten(-2).any(dim=-1)[..., None, None]
    eps = torch.where(any_zero, AUTHORS_LOG_EPS, 0.0).to(p.dtype)
    terms = torch.where(p > 0, -p * torch.log2(torch.where(p > 0, p + eps, torch.ones_like(p))), 0.0)
    return AUTHORS_SCALE * terms.sum(dim=-1)


def ray_entropy(weights: Tensor, mode: str = "escape") -> Tensor:
    """Shannon entropy (bits) of each ray's termination distribution.

    Args:
        weights: Tensor with shape (n_rays, n_samples), volume-rendering weights, each row
            summing to at most 1.
        mode: "escape" (default), "renormalise", "raw" or "authors"; see the module docstring.

    Returns:
        Tensor with shape (n_rays,).

    Example:
        >>> ray_entropy(torch.tensor([[0.25, 0.25, 0.25, 0.25], [1.0, 0.0, 0.0, 0.0]]))
        tensor([2., 0.])
        >>> ray_entropy(torch.tensor([[0.25, 0.25, 0.0, 0.0]]))  # escape bin of mass 0.5
        tensor([1.5000])
    """
    if weights.ndim != 2:
        raise ValueError(f"weights must have shape (n_rays, n_samples), got {tuple(weights.shape)}")
    if mode == "escape":
        escape = (1.0 - weights.sum(dim=-1)).clamp_min(0.0)
        return _neg_p_log2_p(weights).sum(dim=-1) + _neg_p_log2_p(escape)
    if mode == "renormalise":
        total = weights.sum(dim=-1, keepdim=True)
        p = weights / torch.where(total > 0, total, torch.ones_like(total))
        return _neg_p_log2_p(p).sum(dim=-1)
    if mode == "raw":
        return _neg_p_log2_p(weights).sum(dim=-1)
    if mode == "authors":
        return _authors_entropy(weights)
    raise unknown("entropy mode", mode, ENTROPY_MODES)


def minmax_normalise(values: Tensor) -> Tensor:
    """Affinely map `values` (shape (n,)) onto [0, 1]; all zeros when they are all equal."""
    low, high = values.min(), values.max()
    span = high - low
    if span <= 0:
        return torch.zeros_like(values)
    return (values - low) / span


def mean_view_entropy(
    model: nn.Module,
    cameras: Cameras,
    resolution: int = 40,
    chunk: int = 4096,
    mode: str = "escape",
    progress: Callable[[int], None] | None = None,
) -> Tensor:
    """Mean ray entropy of each view, rendered at reduced resolution, with no per-view
    post-processing (in "authors" mode: the mean of their per-ray entropy, max over each view).

    Views are rendered together in batches of about `chunk` rays through the model's
    `render_weights_only` or `render_rays` (eval mode, no gradients; see `nerfaug.uncertainty.rays`),
    so scoring 500 views at 40 x 40 costs one pass over 800k rays; nothing is kept but each
    view's mean.

    Args:
        model: a module with the `NerfModel` interface.
        cameras: the n_views views to score.
        resolution: width of the reduced rendering in pixels (height keeps the aspect ratio).
        chunk: rays per batch (a batch holds whole views).
        mode: as in `ray_entropy`.
        progress: called after each batch with the number of views scored so far.

    Returns:
        Tensor with shape (n_views,), on the cameras' device.
    """
    check_name("entropy mode", mode, ENTROPY_MODES)
    small = reduced_cameras(cameras, resolution)
    n_pixels = small.width * small.height
    scores = []
    for batch in view_batches(len(small), n_pixels, chunk):
        origins, directions = views_rays(small, batch)
        weights = render_weights_no_grad(model, origins, directions, chunk=chunk)
        weights = weights.reshape(len(batch), n_pixels, -1)
        if mode == "authors":
            entropy = _authors_entropy(weights)
        else:
            entropy = ray_entropy(weights.flatten(0, 1), mode).reshape(len(batch), n_pixels)
        scores.append(entropy.mean(dim=-1))
        if progress is not None:
            progress(batch[-1] + 1)
    return torch.cat(scores).to(cameras.camera_to_world.device)


def authors_view_scores(means: Tensor) -> Tensor:
    """The authors' per-view entropy score from per-view means (shape (n_views,)): the cube,
    min-max normalised over the views to [0, 1]."""
    return minmax_normalise(means**3)


def view_entropy(
    model: nn.Module, cameras: Cameras, resolution: int = 40, chunk: int = 4096, mode: str = "escape"
) -> Tensor:
    """Mean ray entropy of each view, rendered at reduced resolution (`mean_view_entropy`).

    Args:
        model: a module with the `NerfModel` interface.
        cameras: the n_views views to score.
        resolution: width of the reduced rendering in pixels (height keeps the aspect ratio).
        chunk: rays per batch (a batch holds whole views).
        mode: as in `ray_entropy`. In "authors" mode the result is the authors' per-view score:
            the cube of the mean, min-max normalised over the views to [0, 1].

    Returns:
        Tensor with shape (n_views,), bits (in [0, 1] for "authors"), on the cameras' device.
    """
    result = mean_view_entropy(model, cameras, resolution, chunk, mode)
    if mode == "authors":
        result = authors_view_scores(result)
    return result
