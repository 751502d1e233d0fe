"""Volume rendering: per-sample weights from densities, and compositing colour, depth, opacity.

For samples i along a ray with density sigma_i over an interval of length delta_i:
    alpha_i = 1 - exp(-sigma_i delta_i)
    T_i     = prod_{j<i} (1 - alpha_j)         (transmittance up to sample i)
    w_i     = T_i alpha_i                       (probability the ray terminates in interval i)
The weights sum to the ray's accumulation (opacity) <= 1; 1 - accumulation is the probability
that the ray escapes to the background.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch
from torch import Tensor


@dataclass
class RenderOutput:
    """What rendering a batch of rays returns.

    Attributes:
        rgb: Tensor with shape (n_rays, 3), composited over the background.
        accumulation: Tensor with shape (n_rays,), sum of the weights (opacity).
        depth: Tensor with shape (n_rays,), expected termination distance (weights-averaged
            interval midpoints, normalised by the accumulation; `far` where it is zero).
        weights: Tensor with shape (n_rays, n_samples), w_i above, of the final (colour) samples.
        t_starts, t_ends: Tensors with shape (n_rays, n_samples), interval bounds along each ray,
            in world units from the ray origin; positions are origin + t * direction.
        extras: whatever a model needs for its losses (e.g. proposal weights); never required.
    """

    rgb: Tensor
    accumulation: Tensor
    depth: Tensor
    weights: Tensor
    t_starts: Tensor
    t_ends: Tensor
    extras: dict | None = None

    def detach(self) -> RenderOutput:
        return RenderOutput(
            **{f.name: getattr(self, f.name).detach() for f in fields(self) if f.name != "extras"}, extras=None
        )

    @staticmethod
    def cat(parts: list[RenderOutput]) -> RenderOutput:
        """Concatenate outputs of ray chunks (same n_samples), dropping extras."""
        return RenderOutput(
            **{
                f.name: torch.cat([getattr(p, f.name) for p in parts])
                for f in fields(RenderOutput)
                if f.name != "extras"
            },
            extras=None,
        )


_MAX_OPTICAL_DEPTH = 80.0


def render_weights(sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
    """Volume-rendering weights and transmittance from densities.

    Args:
        sigmas: Tensor with shape (n_rays, n_samples), densities >= 0.
        deltas: Tensor with shape (n_rays, n_samples), interval lengths >= 0.

    Returns:
        weights: Tensor with shape (n_rays, n_samples), T_i * alpha_i.
        transmittance: Tensor with shape (n_rays, n_samples), T_i (1 at the first sample).

    Example:
        >>> w, t = render_weights(torch.tensor([[0.0, 1e9]]), torch.tensor([[1.0, 1.0]]))
        >>> w.tolist(), t.tolist()
        ([[0.0, 1.0]], [[1.0, 1.0]])
    """
    optical = sigmas * deltas
    # Exclusive cumulative sum in log space: stable where products of (1 - alpha) underflow.
    accumulated = torch.cumsum(optical, dim=-1)
    exclusive = torch.cat([torch.zeros_like(accumulated[..., :1]), accumulated[..., :-1]], dim=-1)
    # exp(-x) for x in (87, 104) is a subnormal float, which is slow on x86 CPUs; beyond
    # _MAX_OPTICAL_DEPTH the transmittance is 0 exactly (and exp(-80) = 2e-35 is already nothing).
    opaque = exclusive > _MAX_OPTICAL_DEPTH
    transmittance = torch.exp(-exclusive.clamp(max=_MAX_OPTICAL_DEPTH)).masked_fill(opaque, 0.0)
    alphas = 1.0 - torch.exp(-optical.clamp(max=_MAX_OPTICAL_DEPTH))
    return transmittance * alphas, transmittance


def composite(
    weights: Tensor, rgbs: Tensor, t_starts: Tensor, t_ends: Tensor, background: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Colour, opacity and depth of rays from their sample weights.

    Args:
        weights: Tensor with shape (n_rays, n_samples).
        rgbs: Tensor with shape (n_rays, n_samples, 3), per-sample colour in [0, 1].
        t_starts, t_ends: Tensors with shape (n_rays, n_samples).
        background: Tensor with shape (3,) or (n_rays, 3), the colour seen by escaping rays;
            None for black.

    Returns:
        rgb (n_rays, 3), accumulation (n_rays,), depth (n_rays,).
    """
    accumulation = weights.sum(dim=-1)
    rgb = (weights[..., None] * rgbs).sum(dim=-2)
    if background is not None:
        rgb = rgb + (1.0 - accumulation[..., None]) * background
    midpoints = 0.5 * (t_starts + t_ends)
    depth = (weights * midpoints).sum(dim=-1) / accumulation.clamp_min(1e-10)
    depth = torch.where(accumulation > 1e-10, depth, t_ends[..., -1])
    return rgb, accumulation, depth
