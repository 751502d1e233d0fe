import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import (
    FORMATS,
    DatasetError,
    Views,
    load_blender,
    load_blender_split,
    load_dataset,
    load_nerfstudio,
    write_blender_split,
    write_nerfstudio,
)
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses


def make_views(n=4, size=16, seed=0, alpha=True) -> Views:
    g = torch.Generator().manual_seed(seed)
    poses = sample_uniform_poses(n, g)
    cams = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
    # 8-bit exact values so a PNG round trip is lossless.
    images = torch.randint(0, 256, (n, size, size, 3), generator=g).float() / 255
    alphas = torch.ones(n, size, size) if alpha else None
    return Views(cams, images, [f"./train/r_{i}" for i in range(n)], alphas)


def test_blender_round_trip_keeps_poses_and_pixels(tmp_path):
    views = make_views()
    write_blender_split(tmp_path, "train", views)
    back = load_blender_split(tmp_path, "train")
    assert torch.equal(back.images, views.images)
    assert torch.allclose(back.cameras.camera_to_world, views.cameras.camera_to_world, atol=1e-6)
    assert back.cameras.fx[0].item() == pytest.approx(views.cameras.fx[0].item(), rel=1e-6)
    assert back.names == ["./train/r_0", "./train/r_1", "./train/r_2", "./train/r_3"]
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    assert meta["frames"][0]["file_path"] == "./train/r_0"  # Blender format omits the extension


def test_lazy_loading_matches_eager(tmp_path):
    write_blender_split(tmp_path, "test", make_views())
    lazy = load_blender_split(tmp_path, "test", lazy=True)
    assert lazy.images is None
    assert torch.equal(lazy.materialised().images, load_blender_split(tmp_path, "test").images)


def test_alpha_composited_over_background_and_downscaled(tmp_path):
    (tmp_path / "train").mkdir()
    rgba = np.zeros((4, 4, 4), np.uint8)
    rgba[..., 0] = 255  # pure red
    rgba[:2, :, 3] = 255  # top half opaque, bottom half transparent
    iio.imwrite(tmp_path / "train" / "a.png", rgba)
    frame = {"file_path": "./train/a", "transform_matrix": np.eye(4).tolist()}
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": [frame]}))
    white = load_blender_split(tmp_path, "train").images[0]
    assert white[0, 0].tolist() == [1.0, 0.0, 0.0] and white[3, 3].tolist() == [1.0, 1.0, 1.0]
    black = load_blender_split(tmp_path, "train", background=(0, 0, 0)).images[0]
    assert black[3, 3].tolist() == [0.0, 0.0, 0.0]
    half = load_blender_split(tmp_path, "train", downscale=2)
    assert half.images.shape == (1, 2, 2, 3) and half.cameras.width == 2
    assert half.images[0, 0, 0].tolist() == [1.0, 0.0, 0.0]
    assert half.cameras.camera_angle_x[0].item() == pytest.approx(0.7, rel=1e-5)


def test_nerfstudio_round_trip_and_auto_detection(tmp_path):
    views = make_views(n=3)
    write_nerfstudio(tmp_path, views)
    back = load_nerfstudio(tmp_path)
    assert torch.equal(back.images, views.images)
    assert torch.allclose(back.cameras.fy, views.cameras.fy)
    assert torch.equal(load_dataset(tmp_path).images, back.images)


def test_load_blender_finds_existing_splits(tmp_path):
    write_blender_split(tmp_path, "train", make_views())
    write_blender_split(tmp_path, "test", make_views(seed=1))
    assert set(load_blender(tmp_path)) == {"train", "test"}


# --- bad input: every error names the file, the field and the value ------------------------


def write_json(tmp_path, meta, name="transforms_train.json"):
    (tmp_path / name).write_text(json.dumps(meta) if not isinstance(meta, str) else meta)


def valid_meta(tmp_path, n=2, size=8):
    write_blender_split(tmp_path, "train", make_views(n=n, size=size))
    return json.loads((tmp_path / "transforms_train.json").read_text())


def test_missing_file_is_named(tmp_path):
    with pytest.raises(DatasetError, match="transforms_train.json: file not found"):
        load_blender_split(tmp_path, "train")


def test_bad_json_reports_line(tmp_path):
    write_json(tmp_path, '{"camera_angle_x": 0.7,\n "frames": [}')
    with pytest.raises(DatasetError, match=r"transforms_train.json: invalid JSON at line 2"):
        load_blender_split(tmp_path, "train")


def test_missing_camera_angle(tmp_path):
    meta = valid_meta(tmp_path)
    del meta["camera_angle_x"]
    write_json(tmp_path, meta)
    with pytest.raises(DatasetError, match="field 'camera_angle_x'"):
        load_blender_split(tmp_path, "train")


def test_missing_nerfstudio_intrinsics(tmp_path):
    write_nerfstudio(tmp_path, make_views(n=2, size=8))
    meta = json.loads((tmp_path / "transforms.json").read_text())
    for frame in meta["frames"]:
        del frame["fl_x"]
    write_json(tmp_path, meta, "transforms.json")
    with pytest.raises(DatasetError, match=r"frames\[0\].fl_x"):
        load_nerfstudio(tmp_path)


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.eye(3).tolist(), "must be 4x4"),
        ([[1, 0, 0, float("nan")]] + np.eye(4)[1:].tolist(), "non-finite"),
        ((np.eye(4) * np.array([2, 1, 1, 1])).tolist(), "not rigid"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]], "not rigid"),  # a reflection
    ],
)
def test_bad_matrix_names_frame_and_value(tmp_path, matrix, message):
    meta = valid_meta(tmp_path)
    meta["frames"][1]["transform_matrix"] = matrix
    write_json(tmp_path, json.dumps(meta).replace("NaN", "NaN"))
    with pytest.raises(DatasetError, match=rf"frames\[1\].transform_matrix.*{message}") as info:
        load_blender_split(tmp_path, "train")
    assert "got" in str(info.value) and "transforms_train.json" in str(info.value)


def test_missing_image_names_the_path(tmp_path):
    meta = valid_meta(tmp_path)
    meta["frames"][0]["file_path"] = "./train/nope"
    write_json(tmp_path, meta)
    with pytest.raises(DatasetError, match=r"frames\[0\].file_path.*image file not found.*nope"):
        load_blender_split(tmp_path, "train")


@pytest.mark.parametrize("lazy", [False, True])
def test_images_of_different_sizes(tmp_path, lazy):
    """Refused as the image is read: when loading, or for a lazy Views when the image is used; the
    error names the frame, both sizes and the file."""
    valid_meta(tmp_path, n=2, size=8)
    iio.imwrite(tmp_path / "train" / "r_1.png", np.zeros((10, 8, 4), np.uint8))
    with pytest.raises(DatasetError, match=r"frames\[1\].file_path.*differs from frames\[0\]'s 8x8.*8x10.*r_1.png"):
        load_blender_split(tmp_path, "train", lazy=lazy).image(1)


def test_image_that_is_not_rgb(tmp_path):
    valid_meta(tmp_path, n=2, size=8)
    iio.imwrite(tmp_path / "train" / "r_0.png", np.zeros((8, 8), np.uint8))  # greyscale
    with pytest.raises(DatasetError, match=r"frames\[0\].file_path.*must be an RGB or RGBA image"):
        load_blender_split(tmp_path, "train")


def test_unknown_folder(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        load_dataset(tmp_path / "missing")
    with pytest.raises(DatasetError, match="no transforms_train.json"):
        load_dataset(tmp_path)


def test_semi_transparent_pixels_round_trip(tmp_path):
    views = make_views(n=2, size=8)
    views.alphas = torch.linspace(0, 1, 64).reshape(8, 8).expand(2, 8, 8).clone()
    # What a loader returns: straight colour composited over white.
    views.images = views.images * views.alphas[..., None] + (1 - views.alphas[..., None])
    write_blender_split(tmp_path, "train", views)
    back = load_blender_split(tmp_path, "train")
    assert (back.images - views.images).abs().max() < 2.5 / 255  # 8-bit quantisation only
    assert (back.alphas - views.alphas).abs().max() < 1 / 255
    assert (tmp_path / "transforms_train.json").stat().st_mode & 0o044  # readable by others


# --- paths from a transforms file never leave the dataset folder ----------------------------


@pytest.fixture
def outside_image(tmp_path):
    """A readable image beside (not inside) the dataset folder `tmp_path / "dataset"`."""
    (tmp_path / "outside").mkdir()
    iio.imwrite(tmp_path / "outside" / "secret.png", np.full((8, 8, 4), 200, np.uint8))
    (tmp_path / "dataset").mkdir()
    return tmp_path / "outside" / "secret.png"


@pytest.mark.parametrize("how", ["dotdot", "absolute", "symlinked_file", "symlinked_folder"])
@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
def test_a_file_path_leaving_the_dataset_folder_is_refused(outside_image, fmt, how):
    root = outside_image.parent.parent / "dataset"
    views = make_views(n=2, size=8)
    json_path = write_blender_split(root, "train", views) if fmt == "blender" else write_nerfstudio(root, views)
    if how == "symlinked_file":
        (root / "link.png").symlink_to(outside_image)
    if how == "symlinked_folder":
        (root / "link").symlink_to(outside_image.parent, target_is_directory=True)
    value = {
        "dotdot": "../outside/secret.png",
        "absolute": str(outside_image),
        "symlinked_file": "link.png",
        "symlinked_folder": "link/secret",
    }[how]
    meta = json.loads(json_path.read_text())
    meta["frames"][1]["file_path"] = value
    json_path.write_text(json.dumps(meta))
    with pytest.raises(DatasetError) as info:
        load_dataset(root, "train")
    message = str(info.value)
    assert message.startswith(f"{json_path}, field 'frames[1].file_path': image path leads outside {root}")
    # One line naming the path as written; nothing of what lies outside (where a link leads).
    assert f"(got {value!r})" in message and "secret.png" not in message.replace(value, "") and "\n" not in message


def test_paths_that_stay_inside_the_folder_are_accepted(tmp_path):
    views = make_views(n=3, size=8)
    json_path = write_blender_split(tmp_path / "data", "train", views)
    (tmp_path / "data" / "alias.png").symlink_to(tmp_path / "data" / "train" / "r_2.png")
    meta = json.loads(json_path.read_text())
    meta["frames"][0]["file_path"] = str(tmp_path / "data" / "train" / "r_0.png")  # absolute, inside
    meta["frames"][1]["file_path"] = "../data/train/r_1"  # leaves and comes back
    meta["frames"][2]["file_path"] = "alias"  # a symlink to a file inside
    json_path.write_text(json.dumps(meta))
    back = load_blender_split(tmp_path / "data", "train")
    assert torch.equal(back.images, views.images)


@pytest.mark.parametrize("value", [17, None, "", "   ", ["a"], "train/r\x000"])
def test_a_file_path_that_is_not_a_path_string_is_refused(tmp_path, value):
    meta = valid_meta(tmp_path)
    meta["frames"][0]["file_path"] = value
    write_json(tmp_path, meta)
    with pytest.raises(DatasetError, match=r"frames\[0\].file_path': file_path must be a non-empty path string"):
        load_blender_split(tmp_path, "train")


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("camera_angle_x", True, "camera_angle_x must be a number"),
        ("camera_angle_x", 10**400, "camera_angle_x must be a number"),
        ("camera_angle_x", 1e-300, "camera_angle_x must be a number"),
    ],
)
def test_camera_angle_must_be_a_usable_number(tmp_path, key, value, message):
    meta = valid_meta(tmp_path)
    meta[key] = value
    write_json(tmp_path, meta)
    with pytest.raises(DatasetError, match=message):
        load_blender_split(tmp_path, "train")


@pytest.mark.parametrize(
    "matrix, message",
    [
        (
            [["1", "0", "0", "0"], ["0", "1", "0", "0"], ["0", "0", "1", "0"], ["0", "0", "0", "1"]],
            "4 rows of 4 numbers",
        ),
        (np.eye(4, dtype=bool).tolist(), "4 rows of 4 numbers"),
        ([[1, 0, 0, 10**400], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "4 rows of 4 numbers"),
        ([[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], "beyond float32 range"),
        ([[1, 0, 0], [0, 1, 0, 0]], "4 rows of 4 numbers"),
    ],
)
def test_matrix_entries_must_be_numbers_float32_can_hold(tmp_path, matrix, message):
    meta = valid_meta(tmp_path)
    meta["frames"][0]["transform_matrix"] = matrix
    write_json(tmp_path, meta)
    with pytest.raises(DatasetError, match=rf"frames\[0\].transform_matrix.*{message}"):
        load_blender_split(tmp_path, "train")


def test_nerfstudio_frames_may_mix_a_field_of_view_and_focal_lengths(tmp_path):
    views = make_views(n=2, size=8)
    write_nerfstudio(tmp_path, views)
    meta = json.loads((tmp_path / "transforms.json").read_text())
    for key in ("fl_x", "fl_y", "cx", "cy"):
        del meta["frames"][1][key]
    meta["frames"][1]["camera_angle_x"] = 0.9
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    cams = load_nerfstudio(tmp_path).cameras
    assert cams.fx[0].item() == pytest.approx(views.cameras.fx[0].item(), rel=1e-6)
    assert cams.fx[1].item() == pytest.approx(0.5 * 8 / math.tan(0.45), rel=1e-6)
    assert cams.cx[1].item() == 4.0


@pytest.mark.parametrize("key, value", [("w", "wide"), ("w", 0), ("fl_x", True), ("cx", float("nan")), ("h", 1e-300)])
def test_nerfstudio_intrinsics_must_be_numbers(tmp_path, key, value):
    write_nerfstudio(tmp_path, make_views(n=2, size=8))
    meta = json.loads((tmp_path / "transforms.json").read_text())
    meta["frames"][1][key] = value
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=rf"field 'frames\[1\].{key}'"):
        load_nerfstudio(tmp_path)


@pytest.mark.parametrize(
    "data, message",
    [
        (b"\x89PNG\r\n\x1a\n" + b"\x00" * 30, "cannot read image"),
        (b"", "cannot read image"),
    ],
)
def test_unreadable_images_give_one_line(tmp_path, data, message):
    valid_meta(tmp_path)
    (tmp_path / "train" / "r_1.png").write_bytes(data)
    with pytest.raises(DatasetError, match=rf"frames\[1\].file_path': {message}") as info:
        load_blender_split(tmp_path, "train")
    assert "\n" not in str(info.value)


def test_an_image_smaller_than_the_downscale_factor_is_refused(tmp_path):
    valid_meta(tmp_path, size=8)
    with pytest.raises(DatasetError, match=r"smaller than the downscale factor 9.*8x8"):
        load_blender_split(tmp_path, "train", downscale=9)


def test_the_blender_format_fits_one_field_of_view_with_a_centred_principal_point(tmp_path):
    views = make_views(n=2, size=8)
    c, blender = views.cameras, FORMATS["blender"]
    assert blender.fits(c) and FORMATS["nerfstudio"].fits(c)
    other_fy = Cameras(c.camera_to_world, c.fx, c.fy * 1.01, c.cx, c.cy, 8, 8)
    off_centre = Cameras(c.camera_to_world, c.fx, c.fy, c.cx + 0.5, c.cy, 8, 8)
    for cameras in (other_fy, off_centre):
        assert not blender.fits(cameras)
        with pytest.raises(ValueError, match="centred principal point; use write_nerfstudio"):
            write_blender_split(tmp_path, "train", Views(cameras, views.images, views.names))
    assert not (tmp_path / "transforms_train.json").exists()
