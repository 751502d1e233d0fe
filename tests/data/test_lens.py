"""Lens distortion in nerfstudio listings: the models against OpenCV's own numbers, and photos of a
known pattern undistorted to the pinhole camera the listing's cameras then have."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
from scipy import optimize

from nerfaug.data.errors import DatasetError
from nerfaug.data.formats import load_dataset
from nerfaug.data.lens import Lens, _photo_pixels, undistortion

RADIAL = Lens("opencv", (-0.21, 0.05, 0.01), (0.003, -0.002))
FISHEYE = Lens("fisheye", (0.08, -0.02, 0.004, -0.001))
POINTS = np.array([[0.3, -0.2], [-0.7, 0.5], [0.05, 0.9]])


@pytest.mark.parametrize(
    ("lens", "expected"),
    [
        # cv2.projectPoints(points (x, y, 1), rvec 0, tvec 0, K = I, D = (k1, k2, p1, p2, k3)), OpenCV 5.0.0
        (RADIAL, [[0.29109009, -0.19384339], [-0.61876257, 0.44313612], [0.04202233, 0.78808942]]),
        # cv2.fisheye.projectPoints(the same, D = (k1, k2, k3, k4)), OpenCV 5.0.0
        (FISHEYE, [[0.29060611, -0.19373741], [-0.59873446, 0.42766747], [0.04222987, 0.76013775]]),
    ],
)
def test_the_models_place_points_where_opencv_does(lens, expected):
    xd, yd = lens.distort(POINTS[:, 0], POINTS[:, 1])
    np.testing.assert_allclose(np.stack([xd, yd], -1), expected, atol=1e-7)


@pytest.mark.parametrize(
    ("lens", "expected"),
    [
        # cv2.initUndistortRectifyMap(K, D, None, K_new, (100, 80), CV_32FC1), OpenCV 5.0.0, with
        # K = [[80, 0, 49.5], [0, 78, 39.5]], K_new = [[90, 0, 49.5], [0, 88, 39.5]]: (row, col) -> (map_x, map_y)
        (RADIAL, {(0, 0): (9.482715, 7.8398275), (10, 90): (83.12164, 15.116823), (79, 3): (11.464939, 71.763695)}),
        # cv2.fisheye.initUndistortRectifyMap(K, D, I, K_new, (100, 80), CV_32FC1)
        (FISHEYE, {(0, 0): (10.174012, 8.2078085), (10, 90): (82.949684, 15.204632), (79, 3): (12.296563, 71.01314)}),
    ],
)
def test_each_pixel_is_taken_from_where_opencv_takes_it(lens, expected):
    # OpenCV's pixel centres are at integers, nerfaug's at i + 0.5: the principal points differ by 0.5.
    for (row, col), (map_x, map_y) in expected.items():
        u, v = _photo_pixels(lens, (80, 78, 50, 40), (90, 88, 50, 40), np.array(col + 0.5), np.array(row + 0.5))
        assert (float(u) - 0.5, float(v) - 0.5) == pytest.approx((map_x, map_y), abs=2e-4)


def pattern(x, y):
    """A smooth colour pattern over the normalised image plane: (..., 3) in [0.1, 0.9]."""
    return np.stack([0.5 + 0.4 * np.sin(6 * x) * np.cos(5 * y), 0.5 + 0.4 * np.cos(4 * x + 3 * y), 0.5 + 0.4 * x], -1)


def photograph(lens, intrinsics, width, height):
    """The pattern as the distorted lens photographs it: each photo pixel's ray found by solving the
    model's forward map with scipy (the loader never inverts it)."""
    fx, fy, cx, cy = intrinsics
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    xd, yd = ((u - cx) / fx).ravel(), ((v - cy) / fy).ravel()

    def residual(xy):
        x, y = xy[: xd.size], xy[xd.size :]
        px, py = lens.distort(x, y)
        return np.concatenate([px - xd, py - yd])

    solved = optimize.root(residual, np.concatenate([xd, yd]), method="krylov", options={"fatol": 1e-12})
    assert np.abs(residual(solved.x)).max() < 1e-9
    x, y = solved.x[: xd.size].reshape(height, width), solved.x[xd.size :].reshape(height, width)
    return pattern(x, y)


def write_listing(root, lens_keys, intrinsics=(80.0, 78.0, 50.0, 40.0), size=(100, 80), photo=None):
    fx, fy, cx, cy = intrinsics
    (root / "images").mkdir(parents=True, exist_ok=True)
    if photo is not None:
        iio.imwrite(root / "images" / "a.png", (photo * 255).round().astype(np.uint8))
    pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    listing = {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": size[0], "h": size[1], **lens_keys}
    listing["frames"] = [{"file_path": "images/a.png", "transform_matrix": pose}]
    (root / "transforms.json").write_text(json.dumps(listing))


@pytest.mark.parametrize(
    ("lens", "keys"),
    [
        (RADIAL, {"camera_model": "OPENCV", "k1": -0.21, "k2": 0.05, "k3": 0.01, "p1": 0.003, "p2": -0.002}),
        (FISHEYE, {"camera_model": "OPENCV_FISHEYE", "k1": 0.08, "k2": -0.02, "k3": 0.004, "k4": -0.001}),
        # pincushion: the photo's border is reached before the frame's, so the camera narrows (s > 1)
        (Lens("opencv", (0.3, 0.0, 0.0)), {"camera_model": "OPENCV", "k1": 0.3}),
    ],
)
def test_a_distorted_photo_loads_as_the_pinhole_view_of_the_same_rays(tmp_path, lens, keys):
    intrinsics, width, height = (80.0, 78.0, 50.0, 40.0), 100, 80
    write_listing(tmp_path, keys, photo=photograph(lens, intrinsics, width, height))
    views = load_dataset(tmp_path)
    cams = views.cameras
    fx, fy, cx, cy = float(cams.fx[0]), float(cams.fy[0]), float(cams.cx[0]), float(cams.cy[0])
    assert (cx, cy) == (50.0, 40.0) and fx / 80.0 == pytest.approx(fy / 78.0)  # one scale, same centre
    # What the pinhole camera the loader reports sees of the pattern, pixel by pixel.
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    expected = pattern((u - cx) / fx, (v - cy) / fy)
    error = np.abs(views.images[0].numpy() - expected)
    assert error.mean() < 2e-3 and error.max() < 0.01, (error.mean(), error.max())
    # Against the same photo read as if it were a pinhole: the distortion is far from negligible.
    write_listing(tmp_path / "as-pinhole", {}, photo=iio.imread(tmp_path / "images" / "a.png") / 255.0)
    plain = load_dataset(tmp_path / "as-pinhole").images[0].numpy()
    naive = np.abs(plain - pattern((u - 50.0) / 80.0, (v - 40.0) / 78.0))
    assert naive.mean() > 10 * error.mean()


def test_every_pixel_of_the_undistorted_image_comes_from_inside_the_photo():
    for lens in (RADIAL, FISHEYE, Lens("opencv", (0.3, 0.0, 0.0)), Lens("opencv", (-0.45, 0.0, 0.0))):
        new, rows, cols = undistortion(lens, (80.0, 78.0, 50.0, 40.0), 100, 80)
        assert rows.min() >= -0.5 - 1e-6 and rows.max() <= 79.5 + 1e-6, lens
        assert cols.min() >= -0.5 - 1e-6 and cols.max() <= 99.5 + 1e-6, lens
        # The smallest such scale: a little wider and some pixel would leave the photo.
        wider = (new[0] * 0.98, new[1] * 0.98, 50.0, 40.0)
        u, v = np.meshgrid(np.arange(100) + 0.5, np.arange(80) + 0.5)
        pu, pv = _photo_pixels(lens, (80.0, 78.0, 50.0, 40.0), wider, u, v)
        strong_barrel = lens.k[0] < -0.3  # folds: bounded by the fold, not by the photo's border
        assert strong_barrel or not ((pu >= 0) & (pu <= 100) & (pv >= 0) & (pv <= 80)).all(), lens


@pytest.mark.parametrize(
    ("keys", "field", "value"),
    [
        ({"camera_model": "EQUIRECTANGULAR"}, "camera_model", "EQUIRECTANGULAR"),
        ({"camera_model": "OPENCV", "k1": 0.1, "k4": 0.2}, "k4", "0.2"),
        ({"camera_model": "OPENCV_FISHEYE", "k1": 0.1, "p1": 0.01}, "p1", "0.01"),
        ({"camera_model": "OPENCV", "k2": "strong"}, "k2", "strong"),
    ],
)
def test_a_lens_nerfaug_cannot_undo_is_refused_in_one_line(tmp_path, keys, field, value):
    write_listing(tmp_path, keys, photo=np.full((80, 100, 3), 0.5))
    with pytest.raises(DatasetError) as caught:
        load_dataset(tmp_path)
    message = str(caught.value)
    assert "transforms.json" in message and field in message and value in message and "\n" not in message


def test_a_frame_names_its_own_distortion(tmp_path):
    write_listing(tmp_path, {"camera_model": "OPENCV"}, photo=np.full((80, 100, 3), 0.5))
    listing = json.loads((tmp_path / "transforms.json").read_text())
    listing["frames"][0]["k1"] = float("nan")
    (tmp_path / "transforms.json").write_text(json.dumps(listing))
    with pytest.raises(DatasetError, match=r"frames\[0\]\.k1"):
        load_dataset(tmp_path)


def test_distorted_photos_leave_their_format_undistorted_and_frames_added_later_are_pinhole(tmp_path):
    from nerfaug.data.formats import find_split, get_format
    from nerfaug.data.interface import NewFrame

    lens, keys = RADIAL, {"camera_model": "OPENCV", "k1": -0.21, "k2": 0.05, "k3": 0.01, "p1": 0.003, "p2": -0.002}
    square = (80.0, 80.0, 50.0, 40.0)  # fx = fy, centred: the Blender format can describe it
    write_listing(tmp_path / "ns", keys, intrinsics=square, photo=photograph(lens, square, 100, 80))
    undistorted = load_dataset(tmp_path / "ns")
    # Into the Blender format (no lens): the undistorted images and the pinhole camera.
    get_format("blender").copy(find_split(tmp_path / "ns"), tmp_path / "bl", "train")
    copied = load_dataset(tmp_path / "bl")
    assert float(copied.cameras.fx[0]) == pytest.approx(float(undistorted.cameras.fx[0]), rel=1e-6)
    assert (copied.images - undistorted.images).abs().max() <= 0.5 / 255 + 1e-6  # one 8-bit rounding
    # A frame appended under the header's lens is an image of the pinhole camera, not a photo to undistort.
    ns = get_format("nerfstudio")
    data = (tmp_path / "ns" / "images" / "a.png").read_bytes()
    pose = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]
    ns.append(tmp_path / "ns", "train", [NewFrame("b", data, ".png", pose)], undistorted.cameras[0:1])
    grown = load_dataset(tmp_path / "ns")
    assert len(grown) == 2 and float(grown.cameras.fx[1]) == pytest.approx(float(undistorted.cameras.fx[0]))
    raw = iio.imread(tmp_path / "ns" / "images" / "a.png") / 255.0
    assert np.abs(grown.images[1].numpy() - raw).max() < 1e-6  # read as it is
    assert ns.lens_distortion(*find_split(tmp_path / "ns").read())


def test_a_shrunk_distorted_photo_is_the_shrunk_camera_and_keeps_its_alpha(tmp_path):
    # RGBA: the left of the image plane (x < 0) is opaque pattern, the right transparent (white).
    lens, keys = RADIAL, {"camera_model": "OPENCV", "k1": -0.21, "k2": 0.05, "k3": 0.01, "p1": 0.003, "p2": -0.002}
    intrinsics, width, height = (80.0, 78.0, 50.0, 40.0), 100, 80
    colour = photograph(lens, intrinsics, width, height)
    # The photo's own rays (solved as `photograph` does) decide the alpha: opaque where x < 0.
    fx, _, cx, _ = intrinsics
    u, _ = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    xd = (u - cx) / fx
    alpha = (xd < 0).astype(np.float64)  # the ray's x has xd's sign but within ~0.002 (tangential terms)
    write_listing(tmp_path, keys, photo=np.concatenate([colour, alpha[..., None]], -1))
    full, half = load_dataset(tmp_path), load_dataset(tmp_path, downscale=2)
    assert half.images.shape[1:3] == (40, 50)
    for key in ("fx", "fy", "cx", "cy"):  # the shrunk photo's camera is the full photo's, shrunk
        assert float(getattr(half.cameras, key)[0]) == pytest.approx(float(getattr(full.cameras, key)[0]) / 2, rel=1e-6)
    cams = half.cameras
    u2, v2 = np.meshgrid(np.arange(50) + 0.5, np.arange(40) + 0.5)
    x, y = (u2 - float(cams.cx[0])) / float(cams.fx[0]), (v2 - float(cams.cy[0])) / float(cams.fy[0])
    image = half.images[0].numpy()
    opaque, clear = x < -0.08, x > 0.08
    assert np.abs(image[opaque] - pattern(x, y)[opaque]).mean() < 6e-3
    assert np.abs(image[clear] - 1.0).max() < 1e-6  # white background, no colour bled in
    assert float(half.alphas[0].numpy()[opaque].min()) == pytest.approx(1.0)
