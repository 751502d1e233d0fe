"""The analytic sphere scene against its geometry: the disc it covers and the colour of its normal."""

import math

import torch

from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, BLENDER_RADIUS, pose_from_angles
from nerfaug.scenes.sphere import SPHERE_RADIUS, sphere_views


def test_the_sphere_covers_the_disc_its_angular_radius_gives_and_shows_its_normal():
    size = 96
    pose = pose_from_angles(torch.tensor([0.7]), torch.tensor([0.9]))  # any pose looking at the centre
    views = sphere_views(pose, "v", size=size)
    # Seen from distance d, the sphere's outline is a cone of half-angle asin(r / d); on the image
    # plane, a disc of radius tan(that) / tan(fov / 2) half-widths.
    half_angle = math.asin(SPHERE_RADIUS / BLENDER_RADIUS)
    disc_px = math.tan(half_angle) / math.tan(BLENDER_CAMERA_ANGLE_X / 2) * size / 2
    covered = views.alphas[0].sum().item()
    assert abs(covered - math.pi * disc_px**2) < 2 * math.pi * disc_px  # within a one-pixel rim
    # The pixel at the centre sees the point nearest the camera, whose normal points at the camera.
    toward_camera = pose[0, :3, 3] / pose[0, :3, 3].norm()
    centre = views.images[0, size // 2, size // 2]
    assert torch.allclose(centre, 0.5 + 0.5 * toward_camera.float(), atol=0.03)
    assert torch.equal(views.images[0, 0, 0], torch.ones(3))  # white where the rays miss
