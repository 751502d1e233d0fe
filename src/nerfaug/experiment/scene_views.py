"""Which views of a dataset a run starts from, may add, and is scored on.

Three kinds of dataset reach the protocol:
- a rendered built-in scene: its pool (train), test and `initial` splits, as rendered;
- a dataset with a test split (NeRF-synthetic): the pool is its train split, the test views are
  spread evenly over its test split (an orbit's first frames would cover only one side);
- a captured set, one listing of every photo (LLFF, IDR/DTU, nerfstudio): the cameras are moved
  into the engine frame (`nerfaug.data.world_frame`: the point they look at as origin, their mean up as
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

from dataclasses import dataclass

from torch import Tensor

from nerfaug.data.world_frame import estimate_hemisphere
from nerfaug.layouts import HELD_OUT_SHARE, Half, held_out_count, split_views


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

    The test views (at most one in `HELD_OUT_SHARE`, and `n_test`) are chosen before, and
    regardless of, the layout, so every layout is scored on the same views (`split_views`, as a
    capture session's sparse start keeps them apart).
    """
    views = len(camera_to_world)
    count = held_out_count(views, n_test)
    if count < 1:  # said before the hemisphere is estimated, which needs 2 of them
        raise ValueError(
            f"a captured set of {views} view{'s' * (views != 1)} is too small to keep test views apart (one in "
            f"{HELD_OUT_SHARE}): capture at least {HELD_OUT_SHARE} views, more for the initial and "
            "candidate views"
        )
    hemisphere = estimate_hemisphere(camera_to_world, up="estimate")
    engine = hemisphere.to_engine(camera_to_world)
    split = split_views(engine, count, n_initial, layout, layouts)
    return CapturedSplit(split.held_out, split.initial, split.pool, hemisphere.to_dict(), split.half)
