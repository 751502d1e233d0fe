"""A minimum angular separation between the views of one selection: with it, no two chosen views
are closer than it; without it (the default), the methods choose exactly as before."""

import math

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import pose_from_angles, sample_uniform_poses
from nerfaug.selection import select_views
from nerfaug.selection.separation import pairwise_angles

MODEL_FREE = ("uniform", "distance", "distance-nbv", "furthest")
# What each method chose from `candidates()` with seed 0 before the separation existed (main at 47d1939).
BEFORE = {
    "uniform": [44, 57, 157, 64, 19, 74],
    "distance": [141, 91, 69, 116, 56, 90],
    "distance-nbv": [122, 115, 161, 127, 36, 113],
    "furthest": [161, 36, 63, 150, 33, 188],
}


def candidates() -> tuple[Cameras, Cameras]:
    """200 candidates uniform on the hemisphere and 6 training views on one side."""
    generator = torch.Generator().manual_seed(3)
    pool = Cameras.from_fov(sample_uniform_poses(200, generator), 0.69, 8, 8)
    train = Cameras.from_fov(pose_from_angles(torch.linspace(0, 2.5, 6), torch.full((6,), 1.0)), 0.69, 8, 8)
    return train, pool


def closest_pair_degrees(cameras: Cameras, indices) -> float:
    angles = pairwise_angles(cameras.camera_to_world[torch.as_tensor(indices, dtype=torch.long)])
    angles.fill_diagonal_(math.inf)
    return math.degrees(float(angles.min()))


@pytest.mark.parametrize("method", MODEL_FREE)
def test_the_default_chooses_exactly_as_before(method):
    train, pool = candidates()
    chosen = select_views(method, None, train, pool, 6, torch.Generator().manual_seed(0))
    assert chosen.indices.tolist() == BEFORE[method]


@pytest.mark.parametrize("method", MODEL_FREE)
def test_a_separation_no_pick_violates_keeps_the_methods_choice(method):
    """The limit only steps in where two picks are too close: a tiny one changes nothing."""
    train, pool = candidates()
    plain = select_views(method, None, train, pool, 6, torch.Generator().manual_seed(0))
    tiny = select_views(method, None, train, pool, 6, torch.Generator().manual_seed(0), min_separation=1e-9)
    assert tiny.indices.tolist() == plain.indices.tolist()
    assert torch.equal(tiny.scores, plain.scores)


@pytest.mark.parametrize("method", MODEL_FREE)
@pytest.mark.parametrize("degrees", [15.0, 35.0])
def test_no_two_views_are_closer_than_the_separation(method, degrees):
    train, pool = candidates()
    for seed in range(3):
        chosen = select_views(
            method, None, train, pool, 6, torch.Generator().manual_seed(seed), min_separation=math.radians(degrees)
        )
        assert len(set(chosen.indices.tolist())) == 6
        assert closest_pair_degrees(pool, chosen.indices) >= degrees - 1e-6


def test_top_k_views_cluster_without_a_separation_and_spread_with_one():
    """The case the option is for: the best-scoring views lie side by side."""
    train, pool = candidates()
    plain = select_views("distance-nbv", None, train, pool, 6, torch.Generator().manual_seed(0))
    assert closest_pair_degrees(pool, plain.indices) < 15.0
    kept = select_views(
        "distance-nbv", None, train, pool, 6, torch.Generator().manual_seed(0), min_separation=math.radians(30)
    )
    assert closest_pair_degrees(pool, kept.indices) >= 30.0 - 1e-6
    assert kept.indices[0] == plain.indices[0]  # the best view is kept; only its neighbours move


def test_a_separation_the_candidates_cannot_meet_is_one_clear_error():
    train, pool = candidates()
    with pytest.raises(ValueError, match=r"cannot choose 6 views at least 100 degrees apart among 200") as error:
        select_views("uniform", None, train, pool, 6, torch.Generator().manual_seed(0), min_separation=1.75)
    assert "\n" not in str(error.value)
