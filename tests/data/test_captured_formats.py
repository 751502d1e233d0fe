"""The captured-set formats: LLFF (`poses_bounds.npy`) and IDR/DTU (`cameras_sphere.npz`), read
from fixtures written by hand in each layout (not by the formats' own writers), and the
preparation of a downloaded dataset (`nerfaug scene prepare`)."""

import json
import os

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.data import FORMATS, DatasetError, find_split, load_dataset
from nerfaug.data.prepare import MARKER_KIND, PREPARED, prepare_dataset
from nerfaug.errors import FolderRefused
from nerfaug.hemisphere import half_hemisphere_poses
from nerfaug.owned import mark


def gl_poses(n=5, radius=3.0):
    return half_hemisphere_poses(n, radius=radius).double().numpy()


def photo(rng, h, w):
    return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)


def llff_fixture(root, n=5, h=12, w=16, focal=20.0, masks=True, mask_suffix="_mask"):
    """An LLFF folder as COLMAP's imgs2poses writes it: rotation columns (down, right, backwards)."""
    rng = np.random.default_rng(1)
    (root / "images").mkdir(parents=True)
    rows = []
    for i, pose in enumerate(gl_poses(n)):
        right, up, back = pose[:3, 0], pose[:3, 1], pose[:3, 2]
        matrix = np.stack([-up, right, back, pose[:3, 3], [h, w, focal]], axis=1)  # 3x5
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
        iio.imwrite(root / "images" / f"IMG_{i:02d}.png", photo(rng, h, w))
        if masks:
            (root / "masks").mkdir(exist_ok=True)
            mask = np.zeros((h, w), np.uint8)
            mask[: h // 2] = 255  # top half is the object
            iio.imwrite(root / "masks" / f"IMG_{i:02d}{mask_suffix}.png", mask)
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def idr_fixture(root, n=4, h=12, w=16, image_folder="image", scale=2.0, shift=(0.5, -1.0, 0.25)):
    """A DTU scan in IDR's layout: world_mat = K [R | t] in OpenCV axes, scale_mat maps the unit
    sphere into the world (x_world = scale * x + shift)."""
    rng = np.random.default_rng(2)
    (root / image_folder).mkdir(parents=True)
    (root / "mask").mkdir()
    intrinsics = np.array([[21.0, 0.0, 7.5], [0.0, 22.0, 6.25], [0.0, 0.0, 1.0]])
    scale_mat = np.eye(4)
    scale_mat[:3, :3] *= scale
    scale_mat[:3, 3] = shift
    arrays = {}
    for i, pose in enumerate(gl_poses(n)):
        world_pose = scale_mat @ pose  # the camera in world units
        rotation_cv = world_pose[:3, :3] / scale @ np.diag([1.0, -1.0, -1.0])  # camera axes in OpenCV
        w2c = rotation_cv.T
        t = -w2c @ world_pose[:3, 3]
        world = np.eye(4)
        world[:3, :4] = intrinsics @ np.concatenate([w2c, t[:, None]], 1)
        arrays[f"world_mat_{i}"] = world * 3.7  # a projection is defined up to scale
        arrays[f"scale_mat_{i}"] = scale_mat
        iio.imwrite(root / image_folder / f"{i:06d}.png", photo(rng, h, w))
        iio.imwrite(root / "mask" / f"{i:03d}.png", np.full((h, w, 3), 255, np.uint8))
    np.savez(root / "cameras_sphere.npz", **arrays)
    return root, intrinsics


def test_both_captured_formats_are_registered_and_detected(tmp_path):
    assert "llff" in FORMATS and "idr" in FORMATS
    assert find_split(llff_fixture(tmp_path / "llff")).format.name == "llff"
    assert find_split(idr_fixture(tmp_path / "idr")[0]).format.name == "idr"


def test_llff_poses_become_opengl_and_masks_become_alpha(tmp_path):
    root = llff_fixture(tmp_path / "scene")
    views = load_dataset(root)
    assert len(views) == 5 and views.names[0] == "images/IMG_00.png"
    assert np.allclose(views.cameras.camera_to_world.double().numpy(), gl_poses(5), atol=1e-6)
    assert views.cameras.fx[0].item() == pytest.approx(20.0) and views.cameras.cx[0].item() == pytest.approx(8.0)
    assert views.alphas is not None
    assert torch.equal(views.alphas[0, :6], torch.ones(6, 16)) and torch.equal(views.alphas[0, 6:], torch.zeros(6, 16))
    assert torch.equal(views.images[0, 6:], torch.ones(6, 16, 3))  # outside the mask: the white background
    half = load_dataset(root, downscale=2)
    assert half.cameras.fx[0].item() == pytest.approx(10.0)  # focal scaled with the image


def test_llff_focal_follows_the_stored_images_when_poses_were_made_for_larger_ones(tmp_path):
    root = llff_fixture(tmp_path / "scene", h=24, w=32, masks=False)  # hwf says 24x32 ...
    for path in (root / "images").iterdir():  # ... but the stored images are half that size
        iio.imwrite(path, iio.imread(path)[::2, ::2])
    views = load_dataset(root)
    assert views.cameras.width == 16 and views.cameras.fx[0].item() == pytest.approx(10.0)


def test_idr_projections_decompose_into_intrinsics_and_poses_in_the_sphere_frame(tmp_path):
    root, intrinsics = idr_fixture(tmp_path / "scan")
    views = load_dataset(root)
    assert np.allclose(views.cameras.camera_to_world.double().numpy(), gl_poses(4), atol=1e-5)
    assert views.cameras.fx[0].item() == pytest.approx(intrinsics[0, 0], rel=1e-5)
    assert views.cameras.fy[0].item() == pytest.approx(intrinsics[1, 1], rel=1e-5)
    assert views.cameras.cy[0].item() == pytest.approx(intrinsics[1, 2], rel=1e-5)
    assert views.alphas is not None and bool((views.alphas == 1).all())
    other = idr_fixture(tmp_path / "scan2", image_folder="images")[0]  # DTU copies name it images/
    assert len(load_dataset(other)) == 4


def test_formats_write_what_they_read(tmp_path):
    views = load_dataset(llff_fixture(tmp_path / "a"))
    for name in ("llff", "idr"):
        FORMATS[name].write(tmp_path / name, "train", views)
        back = load_dataset(tmp_path / name)
        assert find_split(tmp_path / name).format.name == name
        assert torch.allclose(back.cameras.camera_to_world, views.cameras.camera_to_world, atol=1e-5)
        assert torch.allclose(back.cameras.fx, views.cameras.fx)
        assert torch.equal(back.alphas, views.alphas) and torch.allclose(back.images, views.images, atol=1 / 255)


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (
            lambda r: np.save(r / "poses_bounds.npy", np.zeros((5, 15))),
            r"poses_bounds\.npy.*\(n, 17\).*shape \(5, 15\)",
        ),
        (
            lambda r: (r / "images" / "IMG_04.png").unlink(),
            r"poses_bounds\.npy, field 'rows': lists 5 poses for the 4 images",
        ),
        (
            lambda r: (r / "masks" / "IMG_02_mask.png").unlink(),
            r"field 'masks': .*holds masks but none for this image.*IMG_02\.png",
        ),
        (lambda r: (r / "poses_bounds.npy").write_bytes(b"not numpy"), r"poses_bounds\.npy.*cannot read"),
    ],
)
def test_bad_llff_input_is_one_line_naming_file_and_field(tmp_path, damage, message):
    root = llff_fixture(tmp_path / "scene")
    damage(root)
    with pytest.raises(DatasetError, match=message) as caught:
        load_dataset(root)
    assert "\n" not in str(caught.value)


def test_bad_idr_input_names_the_missing_camera(tmp_path):
    root, _ = idr_fixture(tmp_path / "scan")
    arrays = dict(np.load(root / "cameras_sphere.npz"))
    del arrays["world_mat_2"]
    np.savez(root / "cameras_sphere.npz", **arrays)
    with pytest.raises(DatasetError, match=r"cameras_sphere\.npz.*world_mat_2"):
        load_dataset(root)


def test_prepare_shrinks_by_any_factor_merges_masks_and_records_the_source(tmp_path):
    source = llff_fixture(tmp_path / "download", h=12, w=16)
    (source / "LICENSE.md").write_text("CC BY 4.0")
    out = prepare_dataset(source, tmp_path / "prepared", width=10)
    views = load_dataset(out)
    record = json.loads((out / PREPARED).read_text())
    assert record["captured"] and record["format"] == "llff" and len(record["source_digest"]) == 64
    assert (views.cameras.width, views.cameras.height) == (10, 8)  # 12 * 10 / 16 = 7.5 -> 8
    assert views.cameras.fx[0].item() == pytest.approx(20.0 * 10 / 16, rel=1e-6)
    assert views.alphas is not None and 0 < float(views.alphas.mean()) < 1
    assert (out / "SOURCE-LICENSE.md").read_text() == "CC BY 4.0"
    before = (out / "transforms.json").stat().st_mtime_ns
    assert prepare_dataset(source, out, width=10) == out  # the same again: nothing written
    assert (out / "transforms.json").stat().st_mtime_ns == before
    with pytest.raises(ValueError, match="another source or at another width"):
        prepare_dataset(source, out, width=8)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="holds files nerfaug did not write"):
        prepare_dataset(source, tmp_path / "mine", width=8)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


# --- masks and image folders never lead outside the dataset folder -----------------------------


@pytest.mark.parametrize("fmt", ["llff", "idr"])
def test_a_mask_linked_outside_is_refused_before_it_is_opened_whatever_it_leads_to(tmp_path, fmt, monkeypatch):
    """A mask linking out of the folder is refused as a linked image is, with one message
    whether the file outside is an image, another file or missing: no probing of outside files."""
    (tmp_path / "outside").mkdir()
    iio.imwrite(tmp_path / "outside" / "image.png", np.full((12, 16), 255, np.uint8))
    (tmp_path / "outside" / "notes.txt").write_text("private")
    opened = []
    real_imread = iio.imread
    monkeypatch.setattr(iio, "imread", lambda path, *a, **k: opened.append(str(path)) or real_imread(path, *a, **k))
    messages = []
    for target in ("image.png", "notes.txt", "missing.png"):
        folder = tmp_path / f"{fmt}-{target}"
        if fmt == "llff":
            root, mask = llff_fixture(folder), folder / "masks" / "IMG_02_mask.png"
        else:
            root, mask = idr_fixture(folder)[0], folder / "mask" / "002.png"
        mask.unlink()
        mask.symlink_to(tmp_path / "outside" / target)
        opened.clear()
        with pytest.raises(DatasetError) as info:
            load_dataset(root)
        assert not any("outside" in path for path in opened)
        messages.append(str(info.value).replace(str(folder), "ROOT"))
    assert messages[0] == messages[1] == messages[2], messages
    assert "mask path leads outside ROOT" in messages[0] and "\n" not in messages[0]
    assert "image.png" not in messages[0] and "notes.txt" not in messages[0]


def test_a_mask_folder_linked_outside_is_refused_before_it_is_listed(tmp_path):
    root = llff_fixture(tmp_path / "scene")
    (tmp_path / "elsewhere").mkdir()
    for mask in (root / "masks").iterdir():
        mask.rename(tmp_path / "elsewhere" / mask.name)
    (root / "masks").rmdir()
    (root / "masks").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    with pytest.raises(DatasetError, match=r"masks/ folder leads outside .*scene, the folder it must stay in"):
        load_dataset(root)


def test_masks_linked_inside_the_folder_are_read(tmp_path):
    root = llff_fixture(tmp_path / "scene")
    kept = root / "kept"
    (root / "masks").rename(kept)
    (root / "masks").symlink_to(kept, target_is_directory=True)
    assert load_dataset(root).alphas is not None


def test_an_image_link_swapped_after_the_check_is_not_followed(tmp_path):
    """Lazy views read each image later: they open the path resolved when it was checked, so a
    link swapped to a file outside the folder in between is not followed."""
    root = llff_fixture(tmp_path / "scene", masks=False)
    (tmp_path / "outside").mkdir()
    iio.imwrite(tmp_path / "outside" / "secret.png", np.zeros((12, 16, 3), np.uint8))
    kept = root / "kept"
    kept.mkdir()
    image = root / "images" / "IMG_03.png"
    image.rename(kept / image.name)
    image.symlink_to(kept / image.name)
    expected = torch.from_numpy(iio.imread(kept / image.name)).float() / 255
    views = load_dataset(root, lazy=True)
    image.unlink()
    image.symlink_to(tmp_path / "outside" / "secret.png")  # swapped after the check
    assert torch.allclose(views.image(3), expected)


# --- what `prepare` removes, and where it writes ------------------------------------------------


def test_an_interrupted_preparation_holding_a_users_file_is_never_removed(tmp_path):
    """A folder marked as nerfaug's but without prepared.json is an interrupted preparation: it is
    started again only when it holds nothing but what a preparation writes; a user's file in it
    stops the command, naming the folder and the file, and nothing there is removed."""
    source = llff_fixture(tmp_path / "download")
    out = tmp_path / "prepared"
    mark(out, MARKER_KIND)
    (out / "images").mkdir()
    (out / "images" / "frame_0.png").write_bytes(b"half written")
    (out / "thesis.tex").write_text("keep me")
    with pytest.raises(FolderRefused, match=rf"{out}: holds thesis\.tex, which nerfaug did not write") as info:
        prepare_dataset(source, out, width=8)
    assert "\n" not in str(info.value)
    assert (out / "thesis.tex").read_text() == "keep me" and (out / "images" / "frame_0.png").is_file()


def test_an_interrupted_preparation_is_removed_and_done_again_keeping_what_its_hard_links_share(tmp_path):
    source = llff_fixture(tmp_path / "download")
    out = tmp_path / "prepared"
    mark(out, MARKER_KIND)
    (out / "images").mkdir()
    (tmp_path / "users.png").write_bytes(b"the user's bytes")
    os.link(tmp_path / "users.png", out / "images" / "frame_0.png")  # a hard link: the same file
    (out / ".transforms.json.abcd_123.tmp").write_text("{")  # what a killed atomic write leaves
    prepare_dataset(source, out, width=8)
    assert (out / PREPARED).is_file() and len(load_dataset(out)) == 5
    assert (tmp_path / "users.png").read_bytes() == b"the user's bytes"
    assert not (out / ".transforms.json.abcd_123.tmp").exists()


@pytest.mark.parametrize("where", ["inside", "same", "holds"])
def test_prepare_refuses_an_out_folder_inside_the_source_it_only_reads(tmp_path, where):
    source = llff_fixture(tmp_path / "download")
    out = {"inside": source / "prepared", "same": source, "holds": tmp_path}[where]
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with pytest.raises(ValueError, match=rf"--out {out}: lies inside or holds the source {source}, which is only read"):
        prepare_dataset(source, out, width=8)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
