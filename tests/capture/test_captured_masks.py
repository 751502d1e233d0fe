"""A session made on a captured set with masks (LLFF `masks/`, IDR `mask/`) trains on the masked
photos, as `nerfaug scene prepare` prepares them: `nerfaug train DATA` and the service's
`from-dataset` both start it with `CaptureSession.create`, whose copy of the dataset keeps each
mask as its image's alpha (they were dropped without a word)."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession
from nerfaug.capture.requests import SessionSettings
from nerfaug.data import load_dataset
from nerfaug.hemisphere import half_hemisphere_poses

H, W = 12, 16
SETTINGS = SessionSettings(engine="test", estimate_up=True)


def mask_of(i: int) -> np.ndarray:
    """The object's mask of view i: the top rows, fewer for each view (so views differ)."""
    mask = np.zeros((H, W), np.uint8)
    mask[: H // 2 + i] = 255
    return mask


def photos(root, folder: str, masks: str, names: list[str], mask_names: list[str]) -> None:
    rng = np.random.default_rng(0)
    (root / folder).mkdir(parents=True)
    (root / masks).mkdir()
    for i, (name, mask_name) in enumerate(zip(names, mask_names)):
        iio.imwrite(root / folder / name, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        iio.imwrite(root / masks / mask_name, mask_of(i))


def llff_with_masks(root, n: int = 4):
    rows = []
    for pose in half_hemisphere_poses(n, radius=3.0).double().numpy():
        matrix = np.stack([-pose[:3, 1], pose[:3, 0], pose[:3, 2], pose[:3, 3], [H, W, 20.0]], axis=1)
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
    photos(root, "images", "masks", [f"IMG_{i}.png" for i in range(n)], [f"IMG_{i}_mask.png" for i in range(n)])
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def idr_with_masks(root, n: int = 4):
    """Non-square pixels (fx != fy): no single camera_angle_x describes them, so the session keeps
    the views in another format than Blender's."""
    intrinsics = np.array([[21.0, 0.0, 7.5], [0.0, 22.0, 6.25], [0.0, 0.0, 1.0]])
    arrays = {}
    for i, pose in enumerate(half_hemisphere_poses(n, radius=3.0).double().numpy()):
        w2c = (pose[:3, :3] @ np.diag([1.0, -1.0, -1.0])).T
        world = np.eye(4)
        world[:3, :4] = intrinsics @ np.concatenate([w2c, (-w2c @ pose[:3, 3])[:, None]], 1)
        arrays[f"world_mat_{i}"], arrays[f"scale_mat_{i}"] = world, np.eye(4)
    photos(root, "image", "mask", [f"{i:06d}.png" for i in range(n)], [f"{i:03d}.png" for i in range(n)])
    np.savez(root / "cameras_sphere.npz", **arrays)
    return root


@pytest.mark.parametrize(("build", "kept_as"), [(llff_with_masks, "blender"), (idr_with_masks, "nerfstudio")])
def test_a_session_on_a_captured_set_trains_on_its_masked_photos(tmp_path, build, kept_as):
    data = build(tmp_path / "data")
    session = CaptureSession.create(data, tmp_path / "run", SETTINGS)
    assert session.state.dataset.format == kept_as
    views = session.engine_views(0)
    assert views.alphas is not None, "the masks were dropped"
    expected = torch.from_numpy(np.stack([mask_of(i) for i in range(len(views))]) / 255.0).float()
    assert torch.allclose(views.alphas, expected, atol=1 / 255)
    # Outside the mask the photo is the background the session composites over (white).
    assert torch.allclose(views.images[expected == 0], torch.ones(3), atol=1 / 255)
    # Reopened, the session reads the same views (the masks live in its own copy of the dataset).
    reopened = CaptureSession.open(tmp_path / "run").engine_views(0)
    assert torch.allclose(reopened.alphas, views.alphas)


@pytest.mark.parametrize("build", [llff_with_masks, idr_with_masks])
def test_a_captured_set_without_masks_kept_in_its_own_format_keeps_its_cameras(tmp_path, build):
    """Cameras no single camera_angle_x describes keep the session's copy in the source's format,
    with each frame's camera (IDR's `K`, LLFF's `hwf` and bounds) copied (they were lost: KeyError)."""
    data = build(tmp_path / "data")
    for masks in ("masks", "mask"):
        for path in (data / masks).glob("*.png") if (data / masks).is_dir() else []:
            path.unlink()
    if (data / "poses_bounds.npy").is_file():  # one focal length per image: no camera_angle_x fits
        rows = np.load(data / "poses_bounds.npy")
        rows[:, 14] += np.arange(len(rows))
        np.save(data / "poses_bounds.npy", rows)
    session = CaptureSession.create(data, tmp_path / "run", SETTINGS)
    assert session.state.dataset.format == ("llff" if (data / "poses_bounds.npy").is_file() else "idr")
    kept, given = session.cameras, load_dataset(data, lazy=True).cameras
    assert torch.allclose(kept.camera_to_world, given.camera_to_world, atol=1e-5)
    assert torch.allclose(kept.fx, given.fx) and torch.allclose(kept.fy, given.fy)
    assert len(session.engine_views(0)) == 4
