import torch

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import (
    BLENDER_CAMERA_ANGLE_X,
    BLENDER_RADIUS,
    half_hemisphere_poses,
    sample_uniform_poses,
)
from nerfaug.selection.candidates import hemisphere_candidates, matching_poses, pool_candidates


def training() -> Cameras:
    return Cameras.from_fov(half_hemisphere_poses(6), BLENDER_CAMERA_ANGLE_X, 80, 80)


def test_hemisphere_candidates_are_seeded_upper_hemisphere_poses_with_the_templates_intrinsics():
    cams = hemisphere_candidates(training(), 500, torch.Generator().manual_seed(0))
    assert len(cams) == 500
    assert (cams.positions[:, 2] >= -1e-5).all()
    assert torch.allclose(cams.positions.norm(dim=-1), torch.full((500,), BLENDER_RADIUS), atol=1e-4)
    assert (cams.width, cams.height) == (80, 80)
    assert torch.allclose(cams.fx, training().fx[0].expand(500))
    again = hemisphere_candidates(training(), 500, torch.Generator().manual_seed(0))
    assert torch.equal(cams.camera_to_world, again.camera_to_world)


def test_hemisphere_candidates_take_the_radius_from_the_template_unless_given():
    template = Cameras.from_fov(sample_uniform_poses(3, radius=2.5), 0.7, 10, 10)
    radii = hemisphere_candidates(template, 20).positions.norm(dim=-1)
    assert torch.allclose(radii, torch.full((20,), 2.5), atol=1e-4)
    assert torch.allclose(
        hemisphere_candidates(template, 20, radius=3.0).positions.norm(dim=-1), torch.full((20,), 3.0), atol=1e-4
    )


def test_pool_candidates_leave_out_training_views():
    train = training()
    others = sample_uniform_poses(10, torch.Generator().manual_seed(1))
    poses = torch.cat([others[:4], train.camera_to_world[[2, 4]], others[4:]])
    pool = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 80, 80)
    candidates, indices = pool_candidates(pool, train)
    assert indices.tolist() == [0, 1, 2, 3, 6, 7, 8, 9, 10, 11]
    assert torch.equal(candidates.camera_to_world, pool.camera_to_world[indices])
    everything, all_indices = pool_candidates(pool)
    assert len(everything) == 12 and all_indices.tolist() == list(range(12))


def test_matching_needs_both_position_and_orientation():
    pose = half_hemisphere_poses(1)
    moved = pose.clone()
    moved[:, 0, 3] += 0.01
    turned = pose.clone()
    turned[:, :3, :3] = -turned[:, :3, :3] @ torch.diag(torch.tensor([1.0, 1.0, -1.0]))  # same centre, rotated
    assert matching_poses(torch.cat([pose, moved, turned]), pose).tolist() == [True, False, False]
    assert matching_poses(pose, pose[:0]).tolist() == [False]
