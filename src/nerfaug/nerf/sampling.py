"""Where along each ray to sample: the ray's span inside the scene box, stratified intervals in
it, and intervals drawn from a histogram of weights (the proposal sampler's inverse CDF); and
the map from the scene box to the fields' unit cube.

Intervals are given by their edges, a Tensor with shape (n_rays, n_samples + 1), increasing along
each ray; sample i covers [edges[:, i], edges[:, i + 1]] and sits at its midpoint.
"""

from __future__ import annotations

import torch
from torch import Tensor


def ray_box_span(
    origins: Tensor, directions: Tensor, half_size: float, near: float, far: float
) -> tuple[Tensor, Tensor]:
    """Where each ray is inside the box [-half_size, half_size]^3 and within [near, far].

    Args:
        origins, directions: Tensors with shape (n_rays, 3).

    Returns:
        t_min, t_max: Tensors with shape (n_rays,), near <= t_min <= t_max <= far;
        t_min == t_max for a ray that misses.

    Example:
        >>> o, d = torch.tensor([[0.0, 0.0, 4.0]]), torch.tensor([[0.0, 0.0, -1.0]])
        >>> [t.tolist() for t in ray_box_span(o, d, 1.5, 2.0, 6.0)]
        [[2.5], [5.5]]
    """
    # A zero component would give 0 * inf = nan at the slab test; a tiny one gives +-inf.
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t_low = (-half_size - origins) / safe
    t_high = (half_size - origins) / safe
    t_enter = torch.minimum(t_low, t_high).amax(dim=-1).clamp(near, far)
    t_exit = torch.maximum(t_low, t_high).amin(dim=-1).clamp(near, far)
    return t_enter, torch.maximum(t_exit, t_enter)


def unit_cube(points: Tensor, half_size: float) -> Tensor:
    """World points in the box [-half_size, half_size]^3 -> the fields' unit cube [0, 1]^3
    (clamped against round-off). Any shape (..., 3).

    Example:
        >>> unit_cube(torch.tensor([[-1.5, 0.0, 1.5]]), 1.5).tolist()
        [[0.0, 0.5, 1.0]]
    """
    return ((points + half_size) / (2.0 * half_size)).clamp(0.0, 1.0)


def _uniform(shape: tuple[int, ...], generator: torch.Generator | None, device) -> Tensor:
    """Uniform [0, 1) numbers drawn on the generator's device, then moved to `device`."""
    gen_device = generator.device if generator is not None else device
    return torch.rand(shape, generator=generator, device=gen_device).to(device)


def stratified_edges(
    t_min: Tensor,
    t_max: Tensor,
    n_samples: int,
    jitter: bool = False,
    generator: torch.Generator | None = None,
) -> Tensor:
    """Edges of `n_samples` equal intervals covering [t_min, t_max], optionally jittered.

    With `jitter`, every interior edge moves uniformly between the midpoints of its two bins
    (nerfstudio's stratified sampling, with the end edges kept in place), so the intervals stay
    contiguous and exactly cover the span.

    Args:
        t_min, t_max: Tensors with shape (n_rays,).
        generator: the source of the jitter (None: the global generator).

    Returns:
        Tensor with shape (n_rays, n_samples + 1).
    """
    fractions = torch.linspace(0.0, 1.0, n_samples + 1, device=t_min.device).expand(t_min.shape[0], -1)
    if jitter and n_samples > 1:
        mids = 0.5 * (fractions[:, 1:] + fractions[:, :-1])
        lower, upper = mids[:, :-1], mids[:, 1:]
        interior = lower + (upper - lower) * _uniform(tuple(lower.shape), generator, t_min.device)
        fractions = torch.cat([fractions[:, :1], interior, fractions[:, -1:]], dim=-1)
    return t_min[:, None] + fractions * (t_max - t_min)[:, None]


def cdf_positions(n_rays: int, n_edges: int, jitter: bool, generator: torch.Generator | None, device) -> Tensor:
    """Where `sample_pdf` inverts the CDF: evenly spaced in [0, 1], or with `jitter` one uniform
    position in each of `n_edges` equal strata of [0, 1). Returns: Tensor with shape (n_rays, n_edges)."""
    if jitter:
        u = torch.linspace(0.0, 1.0 - 1.0 / n_edges, n_edges, device=device)
        u = u + _uniform((n_rays, n_edges), generator, device) / n_edges
    else:
        u = torch.linspace(0.0, 1.0, n_edges, device=device).expand(n_rays, -1)
    return u.contiguous()


def sample_pdf(
    edges: Tensor,
    weights: Tensor,
    n_samples: int,
    jitter: bool = False,
    generator: torch.Generator | None = None,
    padding: float = 0.01,
) -> Tensor:
    """Intervals placed by inverting the CDF of a piecewise-constant histogram (mip-NeRF 360).

    Args:
        edges: Tensor with shape (n_rays, n_bins + 1), the histogram's bins.
        weights: Tensor with shape (n_rays, n_bins), >= 0; `padding` is added to every bin so
            that empty rays still spread their samples (nerfstudio's histogram padding).
        n_samples: intervals to return.
        jitter: stratified random positions in CDF space instead of evenly spaced ones.

    Returns:
        Tensor with shape (n_rays, n_samples + 1), new edges, no gradient.
    """
    with torch.no_grad():
        padded = weights + padding
        pdf = padded / padded.sum(dim=-1, keepdim=True)
        cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, dim=-1)], dim=-1).clamp(max=1.0)
        u = cdf_positions(edges.shape[0], n_samples + 1, jitter, generator, edges.device)
        above = torch.searchsorted(cdf, u, side="right")
        last = cdf.shape[-1] - 1
        below = (above - 1).clamp(0, last)
        above = above.clamp(0, last)
        cdf_below, cdf_above = cdf.gather(-1, below), cdf.gather(-1, above)
        t_below, t_above = edges.gather(-1, below), edges.gather(-1, above)
        fraction = torch.nan_to_num((u - cdf_below) / (cdf_above - cdf_below), 0.0).clamp(0.0, 1.0)
        return t_below + fraction * (t_above - t_below)
