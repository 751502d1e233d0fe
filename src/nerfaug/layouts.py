"""The initial views' layouts: the half of the hemisphere (of the views' azimuths about +z) a sparse
start takes its views from, the paper's "one half of the hemisphere", turned from layout to layout;
used alike by the experiments (`nerfaug.experiment.scene_views`) and a capture session's sparse
start (`nerfaug train DATA --initial N`). Both also keep the same views of a set without a test
split apart for testing (`split_views`): at most one in `HELD_OUT_SHARE`, spread over all
directions, chosen before and regardless of the layout."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from nerfaug.hemisphere import angles_from_pose, half_hemisphere_poses, in_azimuth_window

LEGACY_HALF_START = math.pi / 2
"""Where the first layout's half starts when the views go all the way round (as the rendered
scenes' `initial` split, `half_hemisphere_poses`' default)."""


HELD_OUT_SHARE = 4
"""A set without a test split keeps at most one view in this many apart for testing, so most
remain candidates."""

HELD_OUT_MOST = 50
"""The most views a set without a test split keeps apart for testing: the study's `n_test`
(`ExperimentConfig`'s default, which a test holds equal; not imported there, which stays free of
torch), also a sparse-started session's."""


@dataclass(frozen=True)
class Half:
    """An azimuth window [start, start + width) about +z, radians."""

    start: float
    width: float

    def contains(self, azimuth: Tensor) -> Tensor:
        return in_azimuth_window(azimuth, self.start, self.width)

    def describe(self) -> str:
        """The window in degrees, as users read it: "90.0 to 270.0 degrees"."""
        start = math.degrees(self.start) % 360
        return f"{start:.1f} to {(start + math.degrees(self.width)) % 360:.1f} degrees"

    def to_dict(self) -> dict:
        return {"start_deg": round(math.degrees(self.start) % 360, 3), "width_deg": round(math.degrees(self.width), 3)}


def directions_of(camera_to_world: Tensor) -> Tensor:
    """Unit vectors from the origin to each camera, shape (n, 3), float64."""
    positions = torch.as_tensor(camera_to_world).double()[:, :3, 3]
    return positions / positions.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def layout_halves(azimuth: Tensor, layouts: int) -> list[Half]:
    """The half each of `layouts` layouts takes its initial views from, given the azimuths
    (radians, shape (n,)) of the views they may come from.

    All the way round (no gap in azimuth wider than a half turn): halves of width pi starting at
    `LEGACY_HALF_START` and turned by 2 pi / layouts each. Otherwise the views cover a wedge of
    width W (a full turn less the widest gap): halves of width W / 2, the first at the wedge's
    start, the last at its end.
    """
    if layouts < 1:
        raise ValueError(f"layouts must be >= 1, got {layouts}")
    ordered = torch.sort(torch.remainder(azimuth.double(), 2 * math.pi))[0]
    gaps = torch.diff(torch.cat([ordered, ordered[:1] + 2 * math.pi]))
    widest = int(gaps.argmax())
    if float(gaps[widest]) <= math.pi:
        return [Half(LEGACY_HALF_START + 2 * math.pi * k / layouts, math.pi) for k in range(layouts)]
    span = 2 * math.pi - float(gaps[widest])
    start = float(ordered[(widest + 1) % len(ordered)])
    # A hair (1e-5 rad) wider than half the wedge, so a view lying on the far edge is inside
    # even after float32 rounding of the azimuths.
    width = span / 2 + 1e-5
    step = 0.0 if layouts == 1 else (span / 2) / (layouts - 1)
    return [Half(start + k * step, width) for k in range(layouts)]


def initial_in_half(camera_to_world: Tensor, n: int, half: Half, eligible: list[int]) -> list[int]:
    """The `n` views among `eligible` (indices into `camera_to_world`, (m, 4, 4) in the engine
    frame) nearest in direction to `n` spiral targets over `half`, each used once.

    Raises:
        ValueError: fewer than `n` eligible views lie in the half.
    """
    azimuth, _, _ = angles_from_pose(camera_to_world)
    inside = [i for i in eligible if bool(half.contains(azimuth[i : i + 1])[0])]
    if len(inside) < n:
        raise ValueError(
            f"only {len(inside)} views lie in the half the initial views come from (azimuths {half.describe()}); "
            f"{n} are needed"
        )
    targets = directions_of(half_hemisphere_poses(n, azimuth_start=half.start, azimuth_width=half.width))
    directions = directions_of(camera_to_world)[inside]
    chosen: list[int] = []
    for target in targets:
        similarity = directions @ target
        similarity[[inside.index(c) for c in chosen]] = -math.inf
        chosen.append(inside[int(similarity.argmax())])
    return chosen


def farthest_directions(directions: Tensor, count: int) -> list[int]:
    """`count` indices of `directions` (n, 3) spread over the sphere by farthest-point sampling
    on the angle between them, starting from index 0 (deterministic)."""
    if count < 1:
        return []
    chosen = [0]
    nearest = directions @ directions[0]  # cosine to the nearest chosen direction, per view
    while len(chosen) < min(count, len(directions)):
        nearest[chosen] = math.inf
        pick = int(nearest.argmin())
        chosen.append(pick)
        nearest = torch.maximum(nearest, directions @ directions[pick])
    return chosen


def held_out_count(views: int, most: int = HELD_OUT_MOST) -> int:
    """How many of `views` views a set without a test split keeps apart: one in `HELD_OUT_SHARE`,
    at most `most` (0 for fewer than `HELD_OUT_SHARE` views)."""
    return min(most, views // HELD_OUT_SHARE)


@dataclass(frozen=True)
class ViewSplit:
    """Indices into a set's views: kept apart for testing, the initial views, the candidates; and
    the half the initial views lie on."""

    held_out: list[int]
    initial: list[int]
    pool: list[int]
    half: Half


def split_views(camera_to_world: Tensor, held_out: int, n_initial: int, layout: int, layouts: int) -> ViewSplit:
    """Held-out, initial and candidate views of a set (`camera_to_world` (n, 4, 4), in the engine
    frame: the origin is the point the cameras look at).

    The `held_out` views (0: none) are spread over all directions (`farthest_directions`) and
    chosen before, and regardless of, the layout, so every layout is scored on the same views; the
    initial views are layout `layout` (of `layouts`) of the others (`initial_in_half`), the rest
    the pool.

    Raises:
        ValueError: fewer than `n_initial` of the others lie in the layout's half.
    """
    kept = sorted(farthest_directions(directions_of(camera_to_world), held_out))
    rest = [i for i in range(len(camera_to_world)) if i not in set(kept)]
    azimuth, _, _ = angles_from_pose(camera_to_world)
    half = layout_halves(azimuth[rest], layouts)[layout % layouts]
    initial = initial_in_half(camera_to_world, n_initial, half, rest)
    pool = [i for i in rest if i not in set(initial)]
    return ViewSplit(kept, initial, pool, half)
