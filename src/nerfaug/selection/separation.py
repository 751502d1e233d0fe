"""Keeping one round's views apart: a minimum angle, about the scene centre, between any two views a
selection returns. Off unless asked for, so the paper's methods choose exactly as written.

The selector runs once as it would without the limit; its picks are kept in the order chosen,
skipping any closer than the limit to one kept before. When fewer than n are kept, the same
selector is asked for the rest among the candidates at least the limit away from every view kept
(the others are not `Request.eligible`), and so on until n are kept. With no pick too close, the
result is the selector's own, unchanged.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch
from torch import Tensor

from nerfaug.selection.interface import Estimate, Request, Selector


def view_directions(camera_to_world: Tensor) -> Tensor:
    """Unit directions from the origin (the scene centre in the engine frame) to each camera.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).

    Returns:
        Tensor with shape (n, 3), float64, on the CPU.
    """
    positions = camera_to_world[:, :3, 3].detach().cpu().double()
    return positions / positions.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def pairwise_angles(camera_to_world: Tensor) -> Tensor:
    """Angles in radians, about the origin, between every two cameras' positions.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).

    Returns:
        Tensor with shape (n, n), float64, in [0, pi].

    Example:
        >>> from nerfaug.hemisphere import pose_from_angles
        >>> poses = pose_from_angles(torch.tensor([0.0, 0.5]), torch.tensor([math.pi / 2] * 2))
        >>> round(float(pairwise_angles(poses)[0, 1]), 6)
        0.5
    """
    directions = view_directions(camera_to_world)
    return torch.arccos((directions @ directions.T).clamp(-1.0, 1.0))


def separated_views(
    request: Request, estimate: Estimate, selector: Selector, min_separation: float
) -> tuple[Tensor, Estimate]:
    """`request.n` candidates chosen by `selector`, no two closer than `min_separation` (see the
    module docstring).

    Args:
        request: what to choose from (its `n`, candidates and generator).
        estimate: the estimator's scores of the candidates.
        selector: the method's selector.
        min_separation: radians, >= 0.

    Returns:
        indices: Tensor with shape (n,), in the order kept.
        estimate: the estimate the first pass chose from (what the scores of the selection are).

    Raises:
        ValueError: the candidates left at least `min_separation` from the views kept are too few.
    """
    if not 0 <= min_separation <= math.pi:
        raise ValueError(f"min_separation {min_separation}: must be in [0, pi] radians")
    directions = view_directions(request.candidates.camera_to_world)
    limit = math.cos(min_separation)
    n_candidates = directions.shape[0]
    blocked = torch.zeros(n_candidates, dtype=torch.bool)
    if request.excluded is not None:
        blocked |= request.excluded.cpu().bool().reshape(-1)
    kept: list[int] = []
    indices, first = selector(request, estimate)
    while True:
        for index in indices.tolist():
            if blocked[index]:
                continue
            kept.append(index)
            # Closer than the limit: the cosine of the angle is above the limit's cosine.
            blocked |= directions @ directions[index] > limit
            blocked[index] = True
            if len(kept) == request.n:
                return torch.tensor(kept, dtype=torch.long), first
        free = ~blocked if request.eligible is None else request.eligible & ~blocked
        if not bool(free.any()):
            raise ValueError(
                f"cannot choose {request.n} views at least {math.degrees(min_separation):.3g} degrees apart "
                f"among {n_candidates} candidates (found {len(kept)}); ask for fewer views, a smaller "
                "separation or more candidates"
            )
        asked = replace(request, n=min(request.n - len(kept), int(free.sum())), excluded=blocked.clone())
        indices, _ = selector(asked, estimate)
