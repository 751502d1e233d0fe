"""`nerfaug eval`'s held-out views: a limited number of them covers the whole test orbit."""

import math

import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.evaluate import load_held_out
from nerfaug.data.blender import load_blender_split, write_blender_split
from nerfaug.data.views import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, angles_from_pose, pose_from_angles


def orbit_dataset(root, n=24, size=8) -> Views:
    """A Blender-format test split whose frames go once round the object, in order (as
    NeRF-synthetic's test orbit does)."""
    azimuths = torch.linspace(0, 2 * math.pi, n + 1)[:-1]
    poses = pose_from_angles(azimuths, torch.full_like(azimuths, 0.5), 4.0)
    images = torch.randint(0, 256, (n, size, size, 3), generator=torch.Generator().manual_seed(0)).float() / 255
    views = Views(
        Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size), images, [f"./test/r_{i}" for i in range(n)]
    )
    write_blender_split(root, "test", views)
    return load_blender_split(root, "test")


def test_a_few_held_out_views_are_spread_over_the_orbit_with_their_own_images(tmp_path):
    full = orbit_dataset(tmp_path)
    held = load_held_out(tmp_path, "test", max_views=6)
    assert len(held) == 6
    azimuth = torch.rad2deg(angles_from_pose(held.cameras.camera_to_world)[0]) % 360
    gaps = torch.diff(torch.sort(azimuth).values, append=azimuth.min()[None] + 360)
    assert float(gaps.max()) < 90  # the first 6 of 24 frames would leave a gap of 285 degrees
    for i, name in enumerate(held.names):
        assert torch.equal(held.image(i), full.images[full.names.index(name)])


def test_all_views_when_the_limit_is_not_below_their_number(tmp_path):
    full = orbit_dataset(tmp_path, n=5)
    assert load_held_out(tmp_path, "test", max_views=9).names == full.names
