"""Where chosen views lie on the hemisphere: their share on the half opposite to the initial
views (for a wedge of cameras, on the part of the wedge the initial views do not come from), and
their spread (the mean angle between their directions from the centre)."""

from __future__ import annotations

import math

import numpy as np
import torch

from nerfaug.hemisphere import angles_from_pose, in_azimuth_window


def seen_half_start(initial_azimuth) -> float:
    """Where the half of the hemisphere the initial views look from begins: their circular-mean
    azimuth minus pi/2, so the seen half is [start, start + pi) (`hemisphere.in_azimuth_window`).
    nan when the initial views surround the object (no mean direction).

    Args:
        initial_azimuth: array or Tensor with shape (n,), radians.
    """
    azimuth = np.asarray(initial_azimuth, dtype=np.float64).reshape(-1)
    if azimuth.size == 0:
        raise ValueError("seen_half_start: no initial views")
    s, c = np.sin(azimuth).mean(), np.cos(azimuth).mean()
    if math.hypot(s, c) < 1e-6:
        return math.nan
    return float(math.atan2(s, c) - math.pi / 2)


def unseen_half_share(chosen_azimuth, initial_azimuth) -> float:
    """The share of chosen views on the unseen half of the hemisphere: the half opposite to the
    initial views (outside `seen_half_start`'s window). nan without chosen views or a seen half.

    Args:
        chosen_azimuth, initial_azimuth: arrays or Tensors with shape (k,) and (n,), radians.

    Example:
        >>> round(unseen_half_share([0.1, 3.0], [math.pi, math.pi]), 2)  # initial views at 180 deg
        0.5
    """
    chosen = torch.as_tensor(np.asarray(chosen_azimuth, dtype=np.float64).reshape(-1))
    start = seen_half_start(initial_azimuth)
    if chosen.numel() == 0 or math.isnan(start):
        return math.nan
    return float((~in_azimuth_window(chosen, start)).double().mean())


def mean_pairwise_angle(directions) -> float:
    """The mean angle, in degrees, between every pair of view directions (a spread: 0 when all
    views coincide; 90 on average for directions uniform on a sphere). nan for fewer than 2.

    Args:
        directions: array with shape (k, 3), e.g. camera positions relative to the centre
            (need not be unit length).
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if d.shape[0] < 2:
        return math.nan
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    i, j = np.triu_indices(d.shape[0], k=1)
    return float(np.degrees(np.arccos(np.clip((d[i] * d[j]).sum(1), -1.0, 1.0))).mean())


def outside_wedge_half_share(chosen_azimuth, half: dict) -> float:
    """The share of chosen views outside `half`, the part of a wedge of cameras (DTU's) that the
    initial views come from: the wedge's other part is its unseen side. nan without chosen views.

    Args:
        chosen_azimuth: array or Tensor with shape (k,), radians.
        half: {"start_deg", "width_deg"}, the azimuth window the initial views were taken from.
    """
    chosen = torch.as_tensor(np.asarray(chosen_azimuth, dtype=np.float64).reshape(-1))
    if chosen.numel() == 0:
        return math.nan
    window = in_azimuth_window(chosen, math.radians(half["start_deg"]), math.radians(half["width_deg"]))
    return float((~window).double().mean())


# A layout's half narrower than this (degrees) is half of a wedge of cameras, not of the hemisphere.
WEDGE_HALF_DEGREES = 179.0


def view_coverage(chosen_poses, initial_poses, centre=(0.0, 0.0, 0.0), half: dict | None = None) -> dict:
    """How the chosen views cover the hemisphere: their share on the unseen half and their spread.

    Args:
        chosen_poses, initial_poses: arrays or Tensors with shape (k, 4, 4) and (n, 4, 4),
            camera-to-world.
        centre: the hemisphere's centre, world space.
        half: the azimuth window the initial views were taken from ({"start_deg", "width_deg"}),
            when known. Where it is half of a wedge of cameras (narrower than a half-turn), the
            unseen side is the rest of the wedge (`outside_wedge_half_share`): the hemisphere's far
            half holds no camera of such a scene.

    Returns:
        dict with unseen_share (`unseen_half_share`, or `outside_wedge_half_share` for a wedge) and
        spread_deg (`mean_pairwise_angle` of the chosen cameras' positions about the centre).
    """
    chosen = torch.as_tensor(np.asarray(chosen_poses, dtype=np.float64)).reshape(-1, 4, 4)
    initial = torch.as_tensor(np.asarray(initial_poses, dtype=np.float64)).reshape(-1, 4, 4)
    chosen_azimuth, _, _ = angles_from_pose(chosen, centre)
    initial_azimuth, _, _ = angles_from_pose(initial, centre)
    offsets = chosen[:, :3, 3].numpy() - np.asarray(centre, dtype=np.float64)
    if half is not None and half["width_deg"] < WEDGE_HALF_DEGREES:
        unseen = outside_wedge_half_share(chosen_azimuth.numpy(), half)
    else:
        unseen = unseen_half_share(chosen_azimuth.numpy(), initial_azimuth.numpy())
    return {"unseen_share": unseen, "spread_deg": mean_pairwise_angle(offsets)}


__all__ = [
    "WEDGE_HALF_DEGREES",
    "mean_pairwise_angle",
    "outside_wedge_half_share",
    "seen_half_start",
    "unseen_half_share",
    "view_coverage",
]
