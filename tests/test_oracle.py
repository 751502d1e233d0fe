"""Tests for nerfaug.oracle: pool look-up and live Blender capture."""

import importlib.util

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles, sample_uniform_poses
from nerfaug.oracle import BlenderOracle, PoolOracle, PoseNotInPool

# Never import bpy here: it must not share a process with torch. Only check that it exists.
blender = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy")


def make_pool(n: int = 12) -> Views:
    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(n, generator)
    images = torch.rand(n, 6, 5, 3, generator=generator)
    alphas = torch.rand(n, 6, 5, generator=generator)
    return Views(Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 5, 6), images, [f"r_{i}" for i in range(n)], alphas)


def test_pool_oracle_returns_the_pool_images_in_the_requested_order():
    pool = make_pool()
    order = [7, 2, 11]
    # Poses that went through float32 JSON still match.
    poses = pool.cameras.camera_to_world[order] + 1e-6
    views = PoolOracle(pool).capture(poses)
    assert torch.equal(views.images, pool.images[order]) and torch.equal(views.alphas, pool.alphas[order])
    assert views.names == ["r_7", "r_2", "r_11"]
    assert torch.equal(views.cameras.camera_to_world, pool.cameras.camera_to_world[order])


def test_pool_oracle_renames_on_request():
    pool = make_pool()
    views = PoolOracle(pool).capture(pool.cameras.camera_to_world[[3]], names=["new"])
    assert views.names == ["new"] and pool.names[3] == "r_3"
    with pytest.raises(ValueError, match="names"):
        PoolOracle(pool).capture(pool.cameras.camera_to_world[[3, 4]], names=["one"])


def test_pool_oracle_names_the_pose_it_cannot_find():
    pool = make_pool()
    unknown = pose_from_angles(torch.tensor([0.123]), torch.tensor([0.456]))
    poses = torch.cat([pool.cameras.camera_to_world[[0]], unknown])
    with pytest.raises(PoseNotInPool, match=r"pose 1 \(camera at .*closest pool pose, 'r_\d+'"):
        PoolOracle(pool).capture(poses)
    nearly = pool.cameras.camera_to_world[[5]].clone()
    nearly[0, 0, 3] += 0.01
    with pytest.raises(PoseNotInPool, match="tolerance"):
        PoolOracle(pool).capture(nearly)
    assert PoolOracle(pool, tolerance=0.02).match(nearly).tolist() == [5]


def test_pool_oracle_from_dataset_composites_over_the_chosen_background(tmp_path):
    pool = make_pool(4)
    write_blender_split(tmp_path, "train", pool)
    black = PoolOracle.from_dataset(tmp_path, background=(0.0, 0.0, 0.0)).capture(pool.cameras.camera_to_world[[2]])
    white = PoolOracle.from_dataset(tmp_path).capture(pool.cameras.camera_to_world[[2]])
    alpha = black.alphas[0, ..., None]
    assert torch.allclose(white.images[0] - black.images[0], 1.0 - alpha, atol=1e-5)


@pytest.mark.slow
@pytest.mark.blender
@blender
def test_blender_oracle_renders_the_object_centred_over_the_background():
    oracle = BlenderOracle("lego", 40, 40, samples=4, background=(0.0, 0.0, 1.0), progress=False)
    pose = pose_from_angles(torch.tensor([1.0]), torch.tensor([0.9]))
    views = oracle.capture(pose)
    assert views.images.shape == (1, 40, 40, 3) and views.alphas.shape == (1, 40, 40)
    assert views.names == ["capture_0"] and torch.allclose(views.cameras.camera_to_world, pose)
    assert torch.allclose(views.cameras.camera_angle_x, torch.tensor(BLENDER_CAMERA_ANGLE_X))
    alpha = views.alphas[0]
    coverage = alpha.mean().item()
    assert 0.03 < coverage < 0.7
    ys, xs = torch.meshgrid(torch.arange(40) + 0.5, torch.arange(40) + 0.5, indexing="ij")
    centroid = torch.stack([(alpha * xs).sum(), (alpha * ys).sum()]) / alpha.sum() / 40
    assert (centroid - 0.5).abs().max() < 0.12
    assert torch.equal(views.images[0, 0, 0], torch.tensor([0.0, 0.0, 1.0]))  # empty corner
    again = oracle.capture(pose)
    assert again.names == ["capture_1"] and torch.equal(again.images, views.images)  # same seed


@blender
def test_blender_oracle_rejects_an_unknown_scene_at_once():
    with pytest.raises(ValueError, match="unknown scene"):
        BlenderOracle("teapot", 8, 8)
