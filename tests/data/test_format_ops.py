"""The operations every `Format` has (`nerfaug.data.interface`): copy between formats (images byte
for byte, except non-PNG into a PNG-only format), append to a split or start one, and the checks
`find_split` makes before anything is read from a folder."""

import json

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.data import FORMATS, DatasetError, DatasetSplit, NewFrame, find_split, load_dataset
from nerfaug.hemisphere import half_hemisphere_poses


def jpeg_nerfstudio(root, n: int = 3, size: int = 8):
    """A nerfstudio folder of JPEG images with one shared, centred camera."""
    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    frames = []
    for i, pose in enumerate(half_hemisphere_poses(n, radius=2.0)):
        iio.imwrite(root / "images" / f"f{i}.jpg", rng.integers(0, 256, (size, size, 3), dtype=np.uint8))
        frames.append({"file_path": f"images/f{i}.jpg", "transform_matrix": pose.tolist()})
    meta = {"fl_x": 9.0, "fl_y": 9.0, "cx": size / 2, "cy": size / 2, "w": size, "h": size, "k1": 0.0}
    (root / "transforms.json").write_text(json.dumps({**meta, "frames": frames}))
    return root


def test_each_format_is_registered_under_its_own_name():
    assert all(name == fmt.name for name, fmt in FORMATS.items())


def test_copies_keep_bytes_unless_the_format_reads_png_only(tmp_path):
    source = find_split(jpeg_nerfstudio(tmp_path / "src"))
    assert source.format is FORMATS["nerfstudio"]
    same = FORMATS["nerfstudio"].copy(source, tmp_path / "ns", "train")
    assert (tmp_path / "ns" / "images" / "f0.jpg").read_bytes() == (tmp_path / "src" / "images" / "f0.jpg").read_bytes()
    assert json.loads(same.read_text())["k1"] == 0.0  # the same format keeps its camera keys
    FORMATS["blender"].copy(source, tmp_path / "bl", "val")
    as_png = load_dataset(tmp_path / "bl", "val")
    assert (tmp_path / "bl" / "val" / "f0.png").is_file()
    assert torch.equal(as_png.images, load_dataset(tmp_path / "src").images)  # lossless: the decoded pixels
    assert torch.allclose(as_png.cameras.fx, torch.full((3,), 9.0))


def test_append_writes_images_then_lists_them_and_can_start_a_split(tmp_path):
    pose = half_hemisphere_poses(1, radius=2.0)[0].tolist()
    camera = Cameras(torch.eye(4), 9.0, 9.0, 4.0, 4.0, 8, 8)
    png = iio.imwrite("<bytes>", np.full((8, 8, 3), 128, np.uint8), extension=".png")
    for name, fmt in FORMATS.items():
        split = DatasetSplit(tmp_path / name, fmt, "train")
        split.append([NewFrame("a", png, ".png", pose)], camera)
        split.append([NewFrame("b", png, ".png", pose)], camera)
        views = split.load()
        assert len(views) == 2 and views.cameras.fx.tolist() == pytest.approx([9.0, 9.0])
    with pytest.raises(ValueError, match="does not fit the blender format"):
        off_centre = Cameras(torch.eye(4), 9.0, 9.0, 3.0, 4.0, 8, 8)
        DatasetSplit(tmp_path / "off", FORMATS["blender"]).append([NewFrame("a", png, ".png", pose)], off_centre)


def test_find_split_refuses_a_listing_linked_from_outside_and_names_what_is_missing(tmp_path):
    jpeg_nerfstudio(tmp_path / "real")
    (tmp_path / "linked").mkdir()
    (tmp_path / "linked" / "transforms.json").symlink_to(tmp_path / "real" / "transforms.json")
    with pytest.raises(DatasetError, match="transforms.json: this listing leads outside"):
        find_split(tmp_path / "linked")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match=r"no transforms_x\.json \(blender format\) nor transforms\.json"):
        find_split(tmp_path / "empty", "x")
    with pytest.raises(DatasetError, match="does not exist"):
        find_split(tmp_path / "nowhere")
