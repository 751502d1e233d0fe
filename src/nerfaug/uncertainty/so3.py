"""Distances between camera rotations on SO(3): the log map, squared geodesic distances, and the
paper's coverage term D (Sec. III-B, Eqs. 3-4).

    f(g1, g2) = 1/2 || log(g1^-1 g2) ||_M^2,        D(g) = sum_n f(g_n, g)

`log` returns the rotation vector (axis times angle, angle in [0, pi]); with M = identity,
||log(g1^-1 g2)|| is the geodesic angle between the rotations, in radians.

Written by hand rather than taken from a library: torch has no SO(3) log, scipy's `Rotation`
works on NumPy arrays (no batched torch, no device, no autograd), and pytorch3d/lietorch would be
heavy dependencies for thirty lines. The tests check every function against scipy.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

# Below this angle theta / sin(theta) is evaluated by its Taylor series (the closed form is 0/0).
_SMALL_ANGLE = 1e-3
# Above this angle the axis is read from the symmetric part of R: the antisymmetric part,
# 2 sin(theta) * axis, vanishes at pi and loses all relative precision near it.
_LARGE_ANGLE = 0.5 * math.pi


def _vee(skew: Tensor) -> Tensor:
    """(..., 3, 3) -> (...,3): the vector of the antisymmetric matrix `skew` (a x b = vee(A) x b)."""
    return torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], dim=-1)


def so3_log(rotation: Tensor) -> Tensor:
    """Rotation vector (log map) of rotation matrices, accurate near angle 0 and near pi.

    Args:
        rotation: Tensor with shape (..., 3, 3), rotation matrices.

    Returns:
        Tensor with shape (..., 3): axis * angle with angle in [0, pi]. At exactly pi the
        sign of the axis is arbitrary (both vectors are logs of the same rotation).

    The angle comes from atan2(sin, cos) with sin = |vee(R - R^T)| / 2 and cos = (tr R - 1) / 2,
    which, unlike arccos(cos), stays accurate at both ends. For angles past pi/2 the axis a is
    read from the symmetric part, (R + R^T) / 2 = cos(theta) I + (1 - cos(theta)) a a^T, using the
    column with the largest diagonal entry; its sign is taken from the antisymmetric part.

    Example:
        >>> so3_log(torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))
        tensor([0.0000, 0.0000, 1.5708])
    """
    if rotation.shape[-2:] != (3, 3):
        raise ValueError(f"rotation must have shape (..., 3, 3), got {tuple(rotation.shape)}")
    antisym = _vee(rotation - rotation.transpose(-1, -2))  # 2 sin(theta) axis
    sin = 0.5 * antisym.norm(dim=-1)
    cos = 0.5 * (rotation.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0)
    angle = torch.atan2(sin, cos)

    # Small and medium angles: log = theta / (2 sin theta) * antisym.
    series = 0.5 * (1.0 + angle**2 / 6.0 + 7.0 * angle**4 / 360.0)
    closed = 0.5 * angle / torch.where(angle < _SMALL_ANGLE, torch.ones_like(sin), sin)
    from_antisym = torch.where(angle < _SMALL_ANGLE, series, closed)[..., None] * antisym

    # Large angles: axis from a a^T = (sym - cos I) / (1 - cos), 1 - cos >= 1 here.
    sym = 0.5 * (rotation + rotation.transpose(-1, -2))
    outer = sym - cos[..., None, None] * torch.eye(3, dtype=rotation.dtype, device=rotation.device)
    outer = outer / (1.0 - cos).clamp_min(1.0)[..., None, None]
    column = outer.diagonal(dim1=-2, dim2=-1).argmax(dim=-1)
    axis = torch.take_along_dim(outer, column[..., None, None].expand(*column.shape, 3, 1), dim=-1)[..., 0]
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    sign = torch.where((axis * antisym).sum(-1) < 0, -1.0, 1.0).to(rotation.dtype)
    from_sym = (sign * angle)[..., None] * axis

    return torch.where((angle > _LARGE_ANGLE)[..., None], from_sym, from_antisym)


def so3_geodesic_sq(rotation1: Tensor, rotation2: Tensor, metric: Tensor | None = None) -> Tensor:
    """Squared distance || log(R1^T R2) ||_M^2 between rotations (R^-1 = R^T on SO(3)).

    Args:
        rotation1, rotation2: Tensors with shapes (..., 3, 3) that broadcast.
        metric: Tensor with shape (3, 3), symmetric positive definite; None for the identity,
            which gives the squared geodesic angle in radians^2.

    Returns:
        Tensor with the broadcast batch shape (...).
    """
    log = so3_log(rotation1.transpose(-1, -2) @ rotation2)
    if metric is None:
        return (log * log).sum(-1)
    metric = torch.as_tensor(metric, dtype=log.dtype, device=log.device)
    if metric.shape != (3, 3):
        raise ValueError(f"metric must have shape (3, 3), got {tuple(metric.shape)}")
    return torch.einsum("...i,ij,...j->...", log, metric, log)


def coverage_distance(candidate_rotations: Tensor, training_rotations: Tensor, metric: Tensor | None = None) -> Tensor:
    """The paper's out-of-distribution term: D(g) = sum_n 1/2 || log(g_n^-1 g) ||_M^2.

    Args:
        candidate_rotations: Tensor with shape (n_candidates, 3, 3), camera-to-world rotations.
        training_rotations: Tensor with shape (n_training, 3, 3), camera-to-world rotations.
        metric: Tensor with shape (3, 3), SPD; None for the identity (the paper's choice).

    Returns:
        Tensor with shape (n_candidates,), in radians^2 for the identity metric; zeros when
        there are no training views.
    """
    pairwise = so3_geodesic_sq(training_rotations[None], candidate_rotations[:, None], metric)
    return 0.5 * pairwise.sum(dim=1)


def min_geodesic_angle(candidate_rotations: Tensor, reference_rotations: Tensor) -> Tensor:
    """Geodesic angle from each candidate to its nearest reference rotation, radians.

    Args:
        candidate_rotations: Tensor with shape (n_candidates, 3, 3).
        reference_rotations: Tensor with shape (n_reference, 3, 3); at least one.

    Returns:
        Tensor with shape (n_candidates,).
    """
    pairwise = so3_geodesic_sq(reference_rotations[None], candidate_rotations[:, None])
    return pairwise.min(dim=1).values.sqrt()
