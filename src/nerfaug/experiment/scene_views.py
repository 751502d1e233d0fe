"""Which views of a dataset a run starts from, may add, and is scored on.

Three kinds of dataset reach the protocol:
- a rendered built-in scene: its pool (train), test and `initial` splits, as rendered;
- a dataset with a test split (NeRF-synthetic): the pool is its train split, the test views are
  spread evenly over its test split (an orbit's first frames would cover only one side);
- a captured set, one listing of every photo (LLFF, IDR/DTU, nerfstudio): the cameras are moved
  into the engine frame (`nerfaug.data.frame`: the point they look at as origin, their mean up as
  +z, their mean distance as NeRF-synthetic's 4.03), the test views are spread over all
  directions (farthest-point sampling) and never candidates, and the rest is the pool.

The initial views come from one half of the views' azimuths about +z (the paper's "one half of
the hemisphere"): a layout is that half, and layout k of `layouts` turns it by a k-th of the
way round, so trials can start from several sides of the object. Where the cameras cover only a
wedge of azimuths (DTU), the half is half of that wedge, slid along it from layout to layout.
Within its half, the initial views are the pool views nearest in direction to a fixed spiral of
targets (`half_hemisphere_poses`), so a layout is the same for every trial and method.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from nerfaug.data.frame import estimate_hemisphere
from nerfaug.hemisphere import angles_from_pose, half_hemisphere_poses, in_azimuth_window

LEGACY_HALF_START = math.pi / 2
"""Where the first layout's half starts when the views go all the way round (as the rendered
scenes' `initial` split, `half_hemisphere_poses`' default)."""
CAPTURED_TEST_SHARE = 4
"""A captured set keeps at most one view in this many for testing, so most remain candidates."""


@dataclass(frozen=True)
class Half:
    """An azimuth window [start, start + width) about +z, radians."""

    start: float
    width: float

    def contains(self, azimuth: Tensor) -> Tensor:
        return in_azimuth_window(azimuth, self.start, self.width)

    def to_dict(self) -> dict:
        return {"start_deg": round(math.degrees(self.start) % 360, 3), "width_deg": round(math.degrees(self.width), 3)}


def directions_of(camera_to_world: Tensor) -> Tensor:
    """Unit vectors from the origin to each camera, shape (n, 3), float64."""
    positions = torch.as_tensor(camera_to_world).double()[:, :3, 3]
    return positions / positions.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def farthest_directions(directions: Tensor, count: int) -> list[int]:
    """`count` indices of `directions` (n, 3) spread over the sphere by farthest-point sampling
    on the angle between them, starting from index 0 (deterministic)."""
    chosen = [0]
    nearest = directions @ directions[0]  # cosine to the nearest chosen direction, per view
    while len(chosen) < min(count, len(directions)):
        nearest[chosen] = math.inf
        pick = int(nearest.argmin())
        chosen.append(pick)
        nearest = torch.maximum(nearest, directions @ directions[pick])
    return chosen


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
            f"only {len(inside)} views lie in the half {half.to_dict()} the initial views come from; {n} are needed"
        )
    targets = directions_of(half_hemisphere_poses(n, azimuth_start=half.start, azimuth_width=half.width))
    directions = directions_of(camera_to_world)[inside]
    chosen: list[int] = []
    for target in targets:
        similarity = directions @ target
        similarity[[inside.index(c) for c in chosen]] = -math.inf
        chosen.append(inside[int(similarity.argmax())])
    return chosen


@dataclass(frozen=True)
class CapturedSplit:
    """How a captured set divides: indices into its views, and the frame it was moved into."""

    test: list[int]
    initial: list[int]
    pool: list[int]
    hemisphere: dict
    half: Half


def split_captured(camera_to_world: Tensor, n_test: int, n_initial: int, layout: int, layouts: int) -> CapturedSplit:
    """Test, initial and candidate views of a captured set (`camera_to_world` (n, 4, 4), any frame).

    The test views (at most one in `CAPTURED_TEST_SHARE`, and `n_test`) are chosen before, and
    regardless of, the layout, so every layout is scored on the same views.
    """
    hemisphere = estimate_hemisphere(camera_to_world, up="estimate")
    engine = hemisphere.to_engine(camera_to_world)
    count = min(n_test, len(engine) // CAPTURED_TEST_SHARE)
    if count < 1:
        raise ValueError(f"a captured set of {len(engine)} views is too small to keep test views apart")
    test = sorted(farthest_directions(directions_of(engine), count))
    rest = [i for i in range(len(engine)) if i not in set(test)]
    azimuth, _, _ = angles_from_pose(engine)
    half = layout_halves(azimuth[rest], layouts)[layout % layouts]
    initial = initial_in_half(engine, n_initial, half, rest)
    pool = [i for i in rest if i not in set(initial)]
    return CapturedSplit(test, initial, pool, hemisphere.to_dict(), half)
