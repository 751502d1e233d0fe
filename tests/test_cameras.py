import math

import pytest
import torch

from nerfaug.cameras import Cameras, generate_rays, image_rays


def identity_camera(width=4, height=2, focal=2.0):
    return Cameras(torch.eye(4), focal, focal, width / 2, height / 2, width, height)


def test_ray_directions_match_hand_computed_pixels():
    cams = identity_camera()
    # Pixel (0, 0) centre is at (0.5, 0.5): x = (0.5 - 2) / 2 = -0.75, y = -(0.5 - 1) / 2 = 0.25, z = -1.
    origins, dirs = generate_rays(cams, torch.tensor([0, 0]), torch.tensor([0, 3]), torch.tensor([0, 1]))
    expected = torch.tensor([[-0.75, 0.25, -1.0], [0.75, -0.25, -1.0]])
    expected = expected / expected.norm(dim=-1, keepdim=True)
    assert torch.allclose(dirs, expected, atol=1e-6)
    assert torch.allclose(origins, torch.zeros(2, 3))


def test_rays_follow_camera_rotation_and_translation():
    # Camera at (1, 2, 3) rotated 90 degrees about +y: its -z axis points along world -x.
    c2w = torch.eye(4)
    c2w[:3, :3] = torch.tensor([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    c2w[:3, 3] = torch.tensor([1.0, 2, 3])
    cams = Cameras(c2w, 10.0, 10.0, 5.0, 5.0, 10, 10)
    o, d = generate_rays(cams, torch.tensor([0]), torch.tensor([4.5]), torch.tensor([4.5]))  # exact centre
    assert torch.allclose(d, torch.tensor([[-1.0, 0, 0]]), atol=1e-6)
    assert torch.allclose(o, torch.tensor([[1.0, 2, 3]]))


def test_focal_from_field_of_view_and_resize():
    cams = Cameras.from_fov(torch.eye(4), 0.6911112070083618, 800, 800)
    assert cams.fx.item() == pytest.approx(400 / math.tan(0.6911112070083618 / 2), rel=1e-6)
    small = cams.resized(100, 100)
    assert small.camera_angle_x.item() == pytest.approx(0.6911112070083618, rel=1e-5)
    assert small.cx.item() == pytest.approx(50.0)


def test_image_rays_row_major_and_unit_length():
    cams = identity_camera(width=5, height=3)
    o, d = image_rays(cams, 0)
    assert d.shape == (15, 3)
    assert torch.allclose(d.norm(dim=-1), torch.ones(15), atol=1e-6)
    image_plane = d[:, :2] / -d[:, 2:]  # (x, y) where the ray meets the plane z = -1
    # Row-major: the second ray is one pixel (1 / focal) right of the first, on the same row.
    assert image_plane[1, 0] - image_plane[0, 0] == pytest.approx(0.5)
    assert image_plane[1, 1] == pytest.approx(image_plane[0, 1].item())
    # The first ray of the second row is one pixel lower (camera +y is up).
    assert image_plane[0, 1] - image_plane[5, 1] == pytest.approx(0.5)


def test_bad_intrinsics_shape_is_rejected():
    with pytest.raises(ValueError, match="fx must have 2 entries"):
        Cameras(torch.eye(4).repeat(2, 1, 1), torch.ones(3), 1.0, 1.0, 1.0, 2, 2)
