import math

import numpy as np
import torch
from scipy import stats

from nerfaug.hemisphere import (
    BLENDER_RADIUS,
    angles_from_pose,
    fibonacci_angles,
    half_hemisphere_poses,
    in_azimuth_window,
    pose_from_angles,
    sample_uniform_angles,
    sample_uniform_poses,
)


def test_pose_looks_at_centre_with_up_towards_z():
    az, po = torch.tensor([0.3, 2.0, 4.0]), torch.tensor([0.4, 1.0, 1.5])
    pose = pose_from_angles(az, po, radius=3.0, centre=(0.1, -0.2, 0.3))
    forward = -pose[:, :3, 2]  # camera looks down -z
    to_centre = torch.tensor([0.1, -0.2, 0.3]) - pose[:, :3, 3]
    assert torch.allclose(forward, to_centre / to_centre.norm(dim=-1, keepdim=True), atol=1e-6)
    assert (pose[:, 2, 1] > 0).all()  # camera +y has a positive world-z component
    rot = pose[:, :3, :3]
    assert torch.allclose(rot.transpose(1, 2) @ rot, torch.eye(3).expand(3, 3, 3), atol=1e-6)
    assert torch.allclose(torch.linalg.det(rot), torch.ones(3), atol=1e-6)


def test_pose_is_defined_at_the_pole():
    pose = pose_from_angles(torch.tensor([1.0]), torch.tensor([0.0]))
    assert torch.isfinite(pose).all()
    assert torch.allclose(pose[0, :3, 3], torch.tensor([0.0, 0.0, BLENDER_RADIUS]), atol=1e-5)


def test_angles_round_trip():
    az, po = sample_uniform_angles(100, torch.Generator().manual_seed(1))
    az2, po2, r = angles_from_pose(pose_from_angles(az, po, radius=2.5))
    assert torch.allclose(az2, az, atol=1e-4)
    assert torch.allclose(po2, po, atol=1e-4)
    assert torch.allclose(r, torch.full((100,), 2.5), atol=1e-5)


def test_uniform_hemisphere_sampling_is_uniform_in_area():
    # Uniform on the hemisphere <=> azimuth ~ U[0, 2pi) and z = cos(polar) ~ U[0, 1].
    poses = sample_uniform_poses(20000, torch.Generator().manual_seed(0), radius=1.0)
    z = poses[:, 2, 3].numpy()
    az = np.mod(np.arctan2(poses[:, 1, 3].numpy(), poses[:, 0, 3].numpy()), 2 * math.pi)
    assert stats.kstest(z, "uniform").pvalue > 0.01
    assert stats.kstest(az / (2 * math.pi), "uniform").pvalue > 0.01
    # A sampler uniform in the polar angle (the common mistake) fails the same test.
    polar = torch.rand(20000, generator=torch.Generator().manual_seed(0)) * math.pi / 2
    assert stats.kstest(torch.cos(polar).numpy(), "uniform").pvalue < 1e-6


def test_half_hemisphere_views_stay_in_their_half_and_differ():
    poses = half_hemisphere_poses(6, azimuth_start=math.pi / 2)
    az, po, _ = angles_from_pose(poses)
    assert in_azimuth_window(az, math.pi / 2).all()
    assert (po > 0).all() and (po < math.pi / 2).all()
    assert torch.cdist(poses[:, :3, 3], poses[:, :3, 3]).add(torch.eye(6) * 10).min() > 0.5
    assert torch.equal(poses, half_hemisphere_poses(6, azimuth_start=math.pi / 2))


def test_azimuth_window_wraps():
    az = torch.tensor([0.1, 6.2, 3.0])
    assert in_azimuth_window(az, start=6.0, width=1.0).tolist() == [True, True, False]


def test_fibonacci_angles_cover_hemisphere():
    az, po = fibonacci_angles(200)
    assert po.max() < math.pi / 2 and po.min() > 0
    assert az.min() >= 0 and az.max() < 2 * math.pi
