import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import (
    DatasetError, Views, load_blender, load_blender_split, load_dataset, load_nerfstudio,
    write_blender_split, write_nerfstudio,
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
    rgba[..., 0] = 255          # pure red
    rgba[:2, :, 3] = 255        # top half opaque, bottom half transparent
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


def test_images_of_different_sizes(tmp_path):
    valid_meta(tmp_path, n=2, size=8)
    iio.imwrite(tmp_path / "train" / "r_1.png", np.zeros((10, 8, 4), np.uint8))
    with pytest.raises(DatasetError, match=r"frames\[1\].file_path.*differs from frames\[0\]'s 8x8.*8x10"):
        load_blender_split(tmp_path, "train")


def test_image_that_is_not_rgb(tmp_path):
    valid_meta(tmp_path, n=2, size=8)
    iio.imwrite(tmp_path / "train" / "r_0.png", np.zeros((8, 8), np.uint8))  # greyscale
    with pytest.raises(DatasetError, match=r"frames\[0\].file_path.*must be RGB or RGBA"):
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
