"""The camera schema (`nerfaug.camera_schema`): every reader and the service hold cameras to one set
of physical rules, and each camera no lens makes is refused in one line naming file, field and
value, while the same camera written at another scale is accepted.

The cases of issue 45: an IDR `scale_mat` that is singular, LLFF focal 1e-30 or image size 1e308,
an IDR scale putting the cameras 3e30 away, OPENCV k1 = -999 or p1 = 500 (refused where they were
taken or raised a traceback), and an IDR `world_mat` scaled by 1e-6 (accepted where it was refused).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from nerfaug import camera_schema
from nerfaug.capture.requests import Intrinsics, RequestError, as_poses, validated
from nerfaug.data import DatasetError, load_dataset
from nerfaug.data.lens import Lens, _area_ratio, undistorted_camera
from nerfaug.data.prepare import prepare_dataset
from nerfaug.hemisphere import half_hemisphere_poses

H, W = 12, 16


def gl_poses(n: int = 4, radius: float = 3.0) -> np.ndarray:
    return half_hemisphere_poses(n, radius=radius).double().numpy()


def write_photos(folder: Path, n: int, masks: Path | None = None) -> None:
    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        iio.imwrite(folder / f"{i:06d}.png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        if masks is not None:
            masks.mkdir(exist_ok=True)
            iio.imwrite(masks / f"{i:03d}.png", np.full((H, W), 255, np.uint8))


def llff(root: Path, focal: float = 20.0, height: float = H, width: float = W, n: int = 4) -> Path:
    rows = []
    for pose in gl_poses(n):
        right, up, back = pose[:3, 0], pose[:3, 1], pose[:3, 2]
        matrix = np.stack([-up, right, back, pose[:3, 3], [height, width, focal]], axis=1)
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
    write_photos(root / "images", n)
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def idr(root: Path, world_scale: float = 1.0, scale_mat=None, n: int = 4) -> Path:
    """IDR's layout with the unit sphere at the world's origin (scale_mat: the identity unless given)."""
    intrinsics = np.array([[21.0, 0.0, 7.5], [0.0, 21.0, 6.25], [0.0, 0.0, 1.0]])
    arrays = {}
    for i, pose in enumerate(gl_poses(n)):
        w2c = (pose[:3, :3] @ np.diag([1.0, -1.0, -1.0])).T
        world = np.eye(4)
        world[:3, :4] = intrinsics @ np.concatenate([w2c, (-w2c @ pose[:3, 3])[:, None]], 1)
        arrays[f"world_mat_{i}"] = world * world_scale
        arrays[f"scale_mat_{i}"] = np.eye(4) if scale_mat is None else np.asarray(scale_mat, dtype=np.float64)
    write_photos(root / "image", n, root / "mask")
    np.savez(root / "cameras_sphere.npz", **arrays)
    return root


def nerfstudio(root: Path, **lens) -> Path:
    write_photos(root / "images", 2)
    frames = [
        {"file_path": f"images/{i:06d}.png", "transform_matrix": pose.tolist()} for i, pose in enumerate(gl_poses(2))
    ]
    listing = {"fl_x": 14.0, "fl_y": 14.0, "cx": W / 2, "cy": H / 2, "w": W, "h": H, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(listing | {"camera_model": "OPENCV"} | lens))
    return root


def refused(call, *names: str) -> str:
    """The one-line refusal `call` raises, checked to name each of `names`."""
    with pytest.raises(DatasetError) as caught:
        call()
    message = str(caught.value)
    assert "\n" not in message
    for name in names:
        assert name in message, (name, message)
    return message


# --- the cases of the issue -------------------------------------------------------------------------


@pytest.mark.parametrize("matrix", [np.zeros((4, 4)), np.diag([1.0, 1.0, 0.0, 1.0])])
def test_a_singular_idr_scale_mat_is_refused_naming_file_and_field(tmp_path, matrix):
    root = idr(tmp_path / "dtu", scale_mat=matrix)
    refused(lambda: load_dataset(root), "cameras_sphere.npz", "scale_mat_0", "singular")


@pytest.mark.parametrize("factor", [1e-6, -1e-6, 1e6, 1e300])
def test_an_idr_world_mat_scaled_by_1e_minus_6_is_the_same_camera(tmp_path, factor):
    plain = load_dataset(idr(tmp_path / "plain"), lazy=True).cameras
    scaled = load_dataset(idr(tmp_path / "scaled", world_scale=factor), lazy=True).cameras
    assert np.allclose(scaled.camera_to_world.numpy(), plain.camera_to_world.numpy(), atol=1e-5)
    assert np.allclose(scaled.fx.numpy(), plain.fx.numpy(), rtol=1e-6)


def test_an_idr_scale_that_puts_the_cameras_3e30_away_is_refused(tmp_path):
    root = idr(tmp_path / "dtu", scale_mat=np.diag([1e-30, 1e-30, 1e-30, 1.0]))
    message = refused(lambda: load_dataset(root), "cameras_sphere.npz", "scale_mat_0", "scene radii")
    assert re.search(r"3e\+30", message)


def test_the_scale_mat_may_be_any_size_when_the_cameras_are_its_size_too(tmp_path):
    """A similarity of scale 1e-30 is fine where the world's cameras are in the same units."""
    root = idr(tmp_path / "dtu", scale_mat=np.diag([1e-30, 1e-30, 1e-30, 1.0]))
    arrays = dict(np.load(root / "cameras_sphere.npz"))
    for key in [k for k in arrays if k.startswith("world_mat")]:
        arrays[key] = arrays[key] @ np.diag([1e30, 1e30, 1e30, 1.0])  # the same cameras, world units 1e-30
    np.savez(root / "cameras_sphere.npz", **arrays)
    radius = load_dataset(root, lazy=True).cameras.positions.norm(dim=-1)
    assert np.allclose(radius.numpy(), 3.0, rtol=1e-5)


@pytest.mark.parametrize(
    ("change", "field", "value"),
    [
        ({"focal": 1e-30}, "row 0", "1e-30"),
        ({"height": 1e308}, "row 0", "1e+308"),
        ({"width": 1e308}, "row 0", "1e+308"),
        ({"focal": 1e9}, "row 0", "1e+09"),  # a 0.000001-degree view
    ],
)
def test_llff_cameras_no_lens_makes_are_refused_before_anything_is_prepared(tmp_path, change, field, value):
    root = llff(tmp_path / "llff", **change)
    refused(lambda: prepare_dataset(root, tmp_path / "out", 8), "poses_bounds.npy", field, value)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("lens", "named"), [({"k1": -999}, "k1=-999"), ({"p1": 500}, "p1=500"), ({"k1": 999}, "k1=999")]
)
def test_a_lens_no_camera_has_is_refused_before_anything_is_prepared(tmp_path, lens, named):
    root = nerfstudio(tmp_path / "ns", **lens)
    message = refused(lambda: prepare_dataset(root, tmp_path / "out", 8), "transforms.json", "frames[0]", named)
    assert "photo pixels per pixel" in message
    assert not (tmp_path / "out").exists()


# --- real cameras still load ------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("lens", "intrinsics", "size"),
    [
        (Lens("fisheye", (0.0, 0.0, 0.0, 0.0)), (4000 / math.pi, 4000 / math.pi, 2000.0, 1500.0), (4000, 3000)),
        (Lens("fisheye", (0.05, 0.01, -0.005, 0.001)), (1100.0, 1100.0, 2000.0, 1500.0), (4000, 3000)),
        (Lens("opencv", (-0.3, 0.1, -0.02), (0.001, 0.001)), (1700.0, 1700.0, 2000.0, 1500.0), (4000, 3000)),
        (Lens("opencv", (-0.45, 0.0, 0.0)), (80.0, 78.0, 50.0, 40.0), (100, 80)),
        (Lens("opencv", (0.3, 0.0, 0.0)), (80.0, 78.0, 50.0, 40.0), (100, 80)),
        (Lens("opencv", (-0.1, 0.2, 0.0)), (2892.0, 2883.0, 823.0, 619.0), (1600, 1200)),
    ],
    ids=["fisheye-180", "action-camera", "phone-ultrawide", "strong-barrel", "pincushion", "dtu"],
)
def test_real_lenses_are_undistorted_and_every_pixel_draws_on_enough_of_the_photo(lens, intrinsics, size):
    fx, fy, cx, cy = intrinsics
    new = undistorted_camera(lens, intrinsics, *size)
    scale = new[0] / fx
    u, v = np.meshgrid(np.linspace(0, size[0], 201), np.linspace(0, size[1], 201))
    drawn = _area_ratio(lens, (u - cx) / new[0], (v - cy) / new[1]) / scale**2
    assert drawn.min() >= camera_schema.MIN_PHOTO_PIXELS_PER_PIXEL * 0.98, drawn.min()
    fov = math.degrees(2 * math.atan(size[0] / 2 / new[0]))
    assert camera_schema.MIN_FOV_DEGREES < fov < camera_schema.MAX_FOV_DEGREES


def test_a_real_dtu_scan_and_llff_capture_load(tmp_path):
    assert len(load_dataset(idr(tmp_path / "dtu"), lazy=True)) == 4
    assert len(load_dataset(llff(tmp_path / "llff"), lazy=True)) == 4


# --- the rules, one by one ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("camera", "key", "says"),
    [
        ((1e-30, 1e-30, 8, 6, 16, 12), "fx", "180 degrees"),
        ((14, 1e9, 8, 6, 16, 12), "fy", "vertical field of view"),
        ((14, 14, -1, 6, 16, 12), "cx", "inside the image"),
        ((14, 14, 8, 13, 16, 12), "cy", "inside the image"),
        ((14, 14, 8, 6, 0.5, 12), "width", "1 to 65536"),
        ((14, 14, 8, 6, 16, 1e308), "height", "1 to 65536"),
        ((float("nan"), 14, 8, 6, 16, 12), "fx", "> 0"),
    ],
)
def test_check_pinhole_names_the_quantity_it_refuses(camera, key, says):
    message = refused(lambda: camera_schema.check_pinhole(*camera, "cams.json", lambda k: f"frames[2].{k}"))
    assert f"field 'frames[2].{key}'" in message and says in message


def test_the_service_holds_intrinsics_to_the_same_schema():
    assert Intrinsics(width=16, height=12, fx=14.0).camera_angle_x == pytest.approx(2 * math.atan(16 / 28))
    for bad, says in (
        ({"width": 16, "height": 12, "fx": 1e-30}, "field of view"),
        ({"width": 16, "height": 12, "fx": 14.0, "cx": 99.0}, "inside the image"),
        ({"width": 10**308, "height": 12, "fx": 14.0}, "65536"),
    ):
        with pytest.raises(RequestError) as caught:
            validated(Intrinsics, bad, "intrinsics")
        assert says in str(caught.value) and "\n" not in str(caught.value)


def test_poses_are_judged_alike_by_the_readers_and_the_service(tmp_path):
    sheared = [[1.0, 0.5, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    with pytest.raises(RequestError) as caught:
        as_poses([sheared])
    problem = caught.value.problem
    with pytest.raises(DatasetError) as read:
        camera_schema.check_pose(sheared, "x.json", "frames[0]")
    assert read.value.problem == problem


def test_every_reader_and_the_service_use_the_one_schema():
    package = Path(camera_schema.__file__).parent
    users = ["data/frames.py", "data/blender.py", "data/nerfstudio.py", "data/llff.py", "data/idr.py", "data/lens.py"]
    for user in [*users, "capture/requests.py"]:
        assert "camera_schema" in (package / user).read_text(), user


@pytest.mark.parametrize("degrees", [0.1, 170.0])
def test_the_field_of_view_bounds_themselves_are_lenses(tmp_path, degrees):
    # The README's range, 0.1 to 170 degrees, holds its ends, as a listing writes them in radians.
    for angle in (math.radians(degrees), float(f"{math.radians(degrees):.12g}")):
        assert camera_schema.check_field_of_view(angle, tmp_path / "t.json", "camera_angle_x") == angle


@pytest.mark.parametrize("degrees", [0.0999, 170.01])
def test_a_field_of_view_just_beyond_the_bounds_is_refused(tmp_path, degrees):
    with pytest.raises(DatasetError, match="camera_angle_x"):
        camera_schema.check_field_of_view(math.radians(degrees), tmp_path / "t.json", "camera_angle_x")
