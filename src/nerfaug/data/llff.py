"""The LLFF format (`poses_bounds.npy` beside `images/`), as COLMAP-based capture tools write it,
with optional object masks in `masks/`.

`poses_bounds.npy` is an (n, 17) float array, one row per image of `images/` in sorted file-name
order: a 3x5 matrix (row-major) whose first three columns are the camera-to-world rotation with
axes (down, right, backwards), the fourth the camera centre and the fifth (height, width, focal
length in pixels) of the images the poses were made for, then the near and far depth bounds.
Here a pose becomes OpenGL camera-to-world (right, up, backwards) and the focal length is scaled
to the size of the stored images; the principal point is the image centre (LLFF's pinhole).

A mask for `images/NAME.EXT` is `masks/NAME.*` or `masks/NAME_mask.*` (white = object); when
the folder has masks, every image needs one, and it becomes the image's alpha.

The whole folder is one listing (no splits): every split reads all of its frames, as with the
nerfstudio format. A captured set is split into initial, candidate and test views by the
experiments (`nerfaug.experiment.protocol`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfaug.camera_schema import check_pinhole
from nerfaug.cameras import Cameras
from nerfaug.containment import inside
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import atomic_write_numpy, check_pose, load_frames
from nerfaug.data.interface import CapturedSetFormat
from nerfaug.data.views import Views

LISTING = "poses_bounds.npy"
IMAGES = "images"
MASKS = "masks"
IMAGE_FILE_SUFFIXES = (".png", ".jpg", ".jpeg")
# LLFF's (down, right, backwards) columns as OpenGL's (right, up, backwards): x = right, y = -down.
LLFF_TO_GL = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def image_files(root: Path, name: str) -> list[Path]:
    """The image files directly in the folder `name` of the dataset folder `root`, sorted by name
    (the order LLFF and IDR list them in).

    The folder must lie inside `root` (`PathRefused` before it is listed); a symbolic link in it is
    listed whatever it leads to (its reader refuses one that leads outside `root`), so that what
    the listing holds says nothing of the files outside.
    """
    folder = inside(root, Path(root) / name, f"{name}/ folder")
    if not folder.is_dir():
        return []
    return sorted(
        p for p in folder.iterdir() if (p.is_symlink() or p.is_file()) and p.suffix.lower() in IMAGE_FILE_SUFFIXES
    )


def matching_masks(images: list[Path], root: Path, listing: Path) -> list[Path] | None:
    """The mask of each image in `root`'s `masks/` (`NAME.*` or `NAME_mask.*`), or None when it
    holds no masks.

    Raises:
        DatasetError: some images have a mask and this one has none.
    """
    folder = Path(root) / MASKS
    masks = image_files(root, MASKS)
    if not masks:
        return None
    by_stem = {p.stem: p for p in masks}
    found = []
    for image in images:
        mask = by_stem.get(image.stem) or by_stem.get(f"{image.stem}_mask")
        if mask is None:
            raise DatasetError(
                listing, f"{folder} holds masks but none for this image", field="masks", value=image.name
            )
        found.append(mask)
    return found


def gl_from_llff(rows: np.ndarray) -> np.ndarray:
    """OpenGL camera-to-world (n, 4, 4) from LLFF's (n, 3, 5) pose matrices."""
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :3] = rows[:, :, :3] @ LLFF_TO_GL.T
    poses[:, :3, 3] = rows[:, :, 3]
    return poses


def llff_from_gl(camera_to_world: np.ndarray) -> np.ndarray:
    """LLFF's (n, 3, 4) rotation and centre from OpenGL camera-to-world (n, 4, 4)."""
    rotation = camera_to_world[:, :3, :3] @ LLFF_TO_GL
    return np.concatenate([rotation, camera_to_world[:, :3, 3:4]], axis=-1)


def read_poses_bounds(path: Path) -> np.ndarray:
    """The (n, 17) array of `poses_bounds.npy`, checked (DatasetError naming the file and row)."""
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise DatasetError(path, f"cannot read this .npy file ({type(error).__name__}: {error})") from None
    if array.ndim != 2 or array.shape[1] != 17 or array.shape[0] == 0 or array.dtype.kind not in "iuf":
        raise DatasetError(path, "must be an (n, 17) array of numbers", value=f"shape {array.shape}, {array.dtype}")
    array = array.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(array).all(axis=1))
    if bad.size:
        raise DatasetError(path, "has non-finite entries", field=f"row {bad[0]}", value=array[bad[0]].tolist())
    for i, (height, width, focal) in enumerate(array[:, :15].reshape(-1, 3, 5)[:, :, 4]):
        # LLFF's pinhole: one focal length, the principal point at the centre.
        check_pinhole(focal, focal, width / 2, height / 2, width, height, path, f"row {i}")
    bad = np.flatnonzero(~((array[:, 15] > 0) & (array[:, 16] > array[:, 15])))
    if bad.size:
        raise DatasetError(
            path, "depth bounds must be 0 < near < far", field=f"row {bad[0]}", value=array[bad[0], 15:].tolist()
        )
    return array


class LlffFormat(CapturedSetFormat):
    """LLFF: `poses_bounds.npy` listing the images of `images/` in name order; masks in `masks/`."""

    name = "llff"
    z_up = False
    fits_rule = "square pixels and the principal point at the image centre"
    listing_name, images, masks = LISTING, IMAGES, MASKS
    camera_keys = ("hwf", "bounds")  # each frame's, as `read_listing` gives them: a copy into this format keeps them

    def read_listing(self, root: Path, split: str) -> tuple[dict, list]:
        """Frames with `file_path`, `transform_matrix` (OpenGL), `hwf` and `bounds`."""
        root = Path(root)
        path = self.listing(root, split)
        array = read_poses_bounds(path)
        images = image_files(root, IMAGES)
        if len(images) != len(array):
            raise DatasetError(
                path,
                f"lists {len(array)} poses for the {len(images)} images in {root / IMAGES}",
                field="rows",
                value=len(array),
            )
        rows = array[:, :15].reshape(-1, 3, 5)
        poses = gl_from_llff(rows)
        frames = []
        for i, (image, pose, row, bounds) in enumerate(zip(images, poses, rows, array[:, 15:])):
            check_pose(pose, path, f"row {i}")
            frames.append(
                {
                    "file_path": f"{IMAGES}/{image.name}",
                    "transform_matrix": pose.tolist(),
                    "hwf": row[:, 4].tolist(),
                    "bounds": bounds.tolist(),
                }
            )
        return {}, frames

    def write_listing(self, root: Path, split: str, header: dict, frames: list) -> Path:
        """`poses_bounds.npy` for `frames`, in the name order of their images (LLFF's pairing)."""
        frames = sorted(frames, key=lambda f: Path(str(f["file_path"])).name)
        known = [f["bounds"] for f in frames if "bounds" in f]
        poses = np.array([f["transform_matrix"] for f in frames], dtype=np.float64)
        rows = []
        for frame, pose in zip(frames, poses):
            # A frame added here has no depth bounds: the other frames' outermost ones, or, for a
            # new folder, the camera's distance to the origin halved and doubled.
            distance = float(np.linalg.norm(pose[:3, 3])) or 1.0
            bounds = frame.get("bounds") or (
                [min(b[0] for b in known), max(b[1] for b in known)] if known else [distance / 2, distance * 2]
            )
            matrix = np.concatenate([llff_from_gl(pose[None])[0], np.array(frame["hwf"], dtype=np.float64)[:, None]], 1)
            rows.append(np.concatenate([matrix.reshape(-1), np.asarray(bounds, dtype=np.float64)]))
        return atomic_write_numpy(self.listing(root, split), np.save, np.stack(rows))

    def load(self, root, split="train", background=(1.0, 1.0, 1.0), downscale=1, lazy=False) -> Views:
        root = Path(root)
        path = self.listing(root, split)
        _, frames = self.read_listing(root, split)
        images = [root / f["file_path"] for f in frames]
        masks = matching_masks(images, root, path)

        def intrinsics_of(width: int, height: int, i: int):
            h, w, focal = frames[i]["hwf"]
            # The poses may have been made for other-sized images (LLFF keeps images_4 beside).
            scale = width / w
            return None, (focal * scale, focal * scale, width / 2.0, height / 2.0)

        return load_frames(
            root,
            path,
            frames,
            background,
            downscale,
            lazy,
            intrinsics_of,
            masks,
            camera_field=lambda i: f"row {i}",
            pose_field=lambda i: f"row {i}",
        )

    def has_masks(self, root: Path) -> bool:
        return bool(image_files(Path(root), MASKS))

    def fits(self, cameras: Cameras) -> bool:
        fx, fy = cameras.fx.double(), cameras.fy.double()
        centred = (cameras.cx.double() - cameras.width / 2).abs().max() < 1e-3 and (
            cameras.cy.double() - cameras.height / 2
        ).abs().max() < 1e-3
        return bool(((fx - fy).abs() <= 1e-6 * fx).all()) and bool(centred)

    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        return {}, [{"hwf": [cameras.height, cameras.width, float(f)]} for f in cameras.fx]
