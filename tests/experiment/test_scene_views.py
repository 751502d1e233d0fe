"""Which views a run starts from, may add and is scored on (`nerfaug.experiment.scene_views`),
and the protocol's use of them on each kind of dataset."""

import math

import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split, write_nerfstudio
from nerfaug.data.views import spread_over_frames
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import load_scene_data
from nerfaug.experiment.scene_views import split_captured
from nerfaug.hemisphere import angles_from_pose, pose_from_angles, sample_uniform_poses
from nerfaug.layouts import Half, farthest_directions, layout_halves


def widest_gap_deg(azimuth) -> float:
    """The widest gap between consecutive azimuths (degrees) around the circle."""
    ordered = np.sort(np.degrees(np.asarray(azimuth)) % 360)
    return float(np.diff(np.concatenate([ordered, ordered[:1] + 360])).max())


def orbit(n=200, polar_deg=60.0, start_deg=90.0, turns=1.0):
    """NeRF-synthetic's test split: an orbit, frame i at azimuth start + 360 * turns * i / n."""
    azimuth = torch.deg2rad(torch.tensor([start_deg + 360.0 * turns * i / n for i in range(n)]))
    return pose_from_angles(azimuth, torch.full((n,), math.radians(polar_deg)))


def views_of(poses, size=8):
    n = len(poses)
    images = torch.rand(n, size, size, 3, generator=torch.Generator().manual_seed(0))
    return Views(Cameras.from_fov(poses, 0.7, size, size), (images * 255).round() / 255, [f"f{i}" for i in range(n)])


def test_the_test_subset_of_an_orbit_covers_it_all_round():
    poses = orbit()
    first = angles_from_pose(poses[:50])[0]
    spread = angles_from_pose(poses[spread_over_frames(50, 200)])[0]
    assert widest_gap_deg(first) > 180  # what the first 50 frames gave: one side of the object
    assert 360 - widest_gap_deg(spread) > 300  # evenly over the frames: the whole orbit
    assert spread_over_frames(50, 200) == sorted(set(spread_over_frames(50, 200)))
    assert spread_over_frames(60, 50) == list(range(50))


def test_farthest_directions_spread_over_the_sphere():
    poses = sample_uniform_poses(400, torch.Generator().manual_seed(1), polar_range=(0.0, math.pi))
    directions = poses[:, :3, 3].double() / poses[:, :3, 3].double().norm(dim=-1, keepdim=True)
    chosen = farthest_directions(directions, 12)
    assert len(set(chosen)) == 12
    gram = directions[chosen] @ directions[chosen].T
    gram.fill_diagonal_(-1)
    # 12 points spread over the sphere: no two closer than 30 degrees (an icosahedron's are 63).
    assert float(gram.max()) < math.cos(math.radians(30))


def test_layout_halves_turn_all_round_or_slide_along_a_wedge():
    full = torch.deg2rad(torch.arange(0.0, 360.0, 10.0))
    halves = layout_halves(full, 3)
    assert [round(math.degrees(h.start)) % 360 for h in halves] == [90, 210, 330]
    assert all(h.width == pytest.approx(math.pi) for h in halves)
    wedge = torch.deg2rad(torch.linspace(300.0, 420.0, 25))  # 120 degrees across 0
    halves = layout_halves(wedge, 3)
    assert [round(math.degrees(h.start)) % 360 for h in halves] == [300, 330, 0]
    for half in halves:
        assert half.width == pytest.approx(math.radians(60), abs=1e-4)
        assert int(half.contains(wedge).sum()) == 13  # half of the wedge's views, its edge included
    with pytest.raises(ValueError, match="layouts must be >= 1"):
        layout_halves(full, 0)


@pytest.mark.parametrize("polar", [(0.2, 1.4), (0.2, 2.6)])  # a hemisphere, or nearly a sphere
def test_a_captured_set_divides_into_test_initial_and_pool_per_layout(polar):
    # A capture in its own units and frame: 80 cameras 7 units from (3, -2, 5), up along -y.
    engine_poses = sample_uniform_poses(80, torch.Generator().manual_seed(2), polar_range=polar).double()
    turn = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)  # +z -> -y
    world = engine_poses.clone()
    world[:, :3, :3] = turn @ engine_poses[:, :3, :3]
    world[:, :3, 3] = (engine_poses[:, :3, 3] / 4.031 * 7.0) @ turn.T + torch.tensor([3.0, -2.0, 5.0])
    splits = [split_captured(world, n_test=50, n_initial=6, layout=k, layouts=3) for k in range(3)]
    first = splits[0]
    assert len(first.test) == 20  # at most a quarter of 80
    assert first.hemisphere["radius"] == pytest.approx(7.0, rel=0.02)
    assert np.allclose(first.hemisphere["centre"], [3.0, -2.0, 5.0], atol=0.05)
    engine_azimuth = angles_from_pose(engine_poses.float())[0]
    assert widest_gap_deg(engine_azimuth[first.test]) < 120  # the test views go all round
    initial_sets = []
    for split in splits:
        assert split.test == first.test  # every layout is scored on the same views
        assert sorted(split.test + split.initial + split.pool) == list(range(80))
        assert not set(split.test) & set(split.pool) and not set(split.initial) & set(split.pool)
        assert len(split.initial) == 6
        initial_sets.append(frozenset(split.initial))
    assert len(set(initial_sets)) == 3  # three different starts
    assert split_captured(world, 50, 6, 1, 3) == splits[1]  # deterministic


def test_protocol_scores_a_nerf_synthetic_dataset_on_its_whole_test_orbit(tmp_path):
    pool = sample_uniform_poses(40, torch.Generator().manual_seed(3))
    write_blender_split(tmp_path, "train", views_of(pool))
    write_blender_split(tmp_path, "test", views_of(orbit(200)))
    config = ExperimentConfig(resolution=8, n_test=50)
    data = load_scene_data(tmp_path, config)
    assert len(data.test) == 50 and 360 - widest_gap_deg(angles_from_pose(data.test.cameras.camera_to_world)[0]) > 300
    assert data.names()["test"][:2] == ["./test/f0", "./test/f4"]
    initial_azimuth = angles_from_pose(data.initial.cameras.camera_to_world)[0]
    assert Half(math.pi / 2 - 0.2, math.pi + 0.4).contains(initial_azimuth).all()  # the first layout's half
    other = load_scene_data(tmp_path, config.replace(layouts=3), layout=1)
    assert other.layout == 1
    assert set(other.initial.names) != set(data.initial.names)
    assert len(other.initial) + len(other.pool) == 40


def test_protocol_moves_a_captured_set_into_the_engine_frame(tmp_path):
    poses = sample_uniform_poses(60, torch.Generator().manual_seed(4)).double()
    poses[:, :3, 3] = poses[:, :3, 3] * 2.0 + torch.tensor([10.0, 0.0, 0.0])  # radius 8, off the origin
    write_nerfstudio(tmp_path, views_of(poses.float()))
    data = load_scene_data(tmp_path, ExperimentConfig(resolution=8, n_test=10))
    radius = data.pool.cameras.camera_to_world[:, :3, 3].norm(dim=-1)
    assert float(radius.mean()) == pytest.approx(4.031, rel=0.02)
    assert len(data.test) == 10 and len(data.initial) == 6 and len(data.pool) == 44
    assert data.record["test_rule"] == "spread over all directions" and "frame" in data.record
