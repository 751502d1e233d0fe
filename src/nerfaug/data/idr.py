"""The IDR / NeuS format of DTU scans: `cameras_sphere.npz` beside `image/` (or `images/`) and
`mask/`.

`cameras_sphere.npz` holds, for image i of the image folder in sorted file-name order,
`world_mat_i`, the 4x4 projection K [R | t] (OpenCV: x right, y down, z forward), and
`scale_mat_i`, the similarity that maps the unit sphere around the object into the world. As
IDR and NeuS do, the cameras are read in the sphere's frame (P = world_mat @ scale_mat), so the
object lies inside the unit sphere, and each projection is split into intrinsics and pose by an
RQ decomposition. Masks (`mask/`, in the same sorted order; white = object) become the alpha.

One listing for the whole folder (no splits), like the nerfstudio and LLFF formats.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from nerfaug.camera_schema import check_projection, check_scene_distance, check_similarity
from nerfaug.cameras import Cameras
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import atomic_write_numpy, check_pose, load_frames
from nerfaug.data.interface import CapturedSetFormat
from nerfaug.data.llff import image_files
from nerfaug.data.views import Views

LISTING = "cameras_sphere.npz"
IMAGE_FOLDERS = ("image", "images")  # IDR writes image/, several DTU copies images/
MASKS = "mask"
# OpenCV's camera axes (right, down, forward) as OpenGL's (right, up, backwards).
CV_TO_GL = np.diag([1.0, -1.0, -1.0])


def decompose_projection(projection: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics and OpenGL camera-to-world of a 3x4 projection matrix P = K [R | t].

    Returns:
        K (3, 3) upper triangular with a positive diagonal and K[2, 2] = 1, and the camera-to-world
        (4, 4). The sign ambiguity of RQ is fixed by making K's diagonal positive; a projection
        with det < 0 (a mirrored camera) is negated first, since P and -P project alike.
    """
    import scipy.linalg  # here, not at the top: every command imports the formats' modules

    projection = np.asarray(projection, dtype=np.float64)
    projection = projection / np.abs(projection).max()  # P and s P are one camera: keep the numbers near 1
    if np.linalg.det(projection[:, :3]) < 0:
        projection = -projection
    intrinsics, rotation = scipy.linalg.rq(projection[:, :3])
    signs = np.diag(np.sign(np.diag(intrinsics)))
    intrinsics, rotation = intrinsics @ signs, signs @ rotation
    centre = -np.linalg.solve(projection[:, :3], projection[:, 3])
    pose = np.eye(4)
    pose[:3, :3] = rotation.T @ CV_TO_GL
    pose[:3, 3] = centre
    return intrinsics / intrinsics[2, 2], pose


def projection_from(intrinsics: np.ndarray, camera_to_world: np.ndarray) -> np.ndarray:
    """The 4x4 `world_mat` K [R | t] of OpenGL camera-to-world (4, 4) and intrinsics (3, 3)."""
    rotation = (camera_to_world[:3, :3] @ CV_TO_GL).T  # world-to-camera, OpenCV axes
    translation = -rotation @ camera_to_world[:3, 3]
    world = np.eye(4)
    world[:3, :4] = intrinsics @ np.concatenate([rotation, translation[:, None]], axis=1)
    return world


class IdrFormat(CapturedSetFormat):
    """IDR / NeuS (DTU): `cameras_sphere.npz` with the images of `image/` in name order, masks in `mask/`."""

    name = "idr"
    z_up = False
    fits_rule = "any pinhole cameras"
    listing_name, images, masks = LISTING, IMAGE_FOLDERS[0], MASKS
    camera_keys = ("K",)  # each frame's, as `read_listing` gives it: a copy into this format keeps them

    def stored_image_folder(self, root: Path) -> str:
        """The image folder a folder uses: `image/`, or `images/` where only that exists."""
        return next((f for f in IMAGE_FOLDERS if image_files(Path(root), f)), IMAGE_FOLDERS[0])

    def read_listing(self, root: Path, split: str) -> tuple[dict, list]:
        """Frames with `file_path`, `transform_matrix` (OpenGL, the sphere's frame) and `K`."""
        root = Path(root)
        path = self.listing(root, split)
        folder = self.stored_image_folder(root)
        images = image_files(root, folder)
        if not images:
            raise DatasetError(path, f"no images in {root / IMAGE_FOLDERS[0]} (nor {root / IMAGE_FOLDERS[1]})")
        try:
            with np.load(path, allow_pickle=False) as npz:
                arrays = {k: np.asarray(npz[k]) for k in npz.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise DatasetError(path, f"cannot read this .npz file ({type(error).__name__})") from None
        frames = []
        for i, image in enumerate(images):
            world = self._matrix(arrays, f"world_mat_{i}", path, required=True)
            scale = self._matrix(arrays, f"scale_mat_{i}", path, required=False)
            # Both are defined up to scale (P and s P are one camera): judged scale-free.
            check_projection(world, path, f"world_mat_{i}")
            check_similarity(scale, path, f"scale_mat_{i}")
            intrinsics, pose = decompose_projection((world @ scale)[:3, :4])
            check_pose(pose, path, f"world_mat_{i}")
            if f"scale_mat_{i}" in arrays:  # the scene's scale: the object inside the unit sphere
                check_scene_distance(float(np.linalg.norm(pose[:3, 3])), path, f"scale_mat_{i}")
            frames.append(
                {
                    "file_path": f"{folder}/{image.name}",
                    "transform_matrix": pose.tolist(),
                    "K": [intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2], intrinsics[0, 1]],
                }
            )
        return {}, frames

    @staticmethod
    def _matrix(arrays: dict, key: str, path: Path, required: bool) -> np.ndarray:
        if key not in arrays:
            if required:
                raise DatasetError(path, "missing the camera of an image (one world_mat_i per image)", field=key)
            return np.eye(4)
        matrix = arrays[key]
        if matrix.shape not in ((4, 4), (3, 4)) or matrix.dtype.kind not in "iuf" or not np.isfinite(matrix).all():
            raise DatasetError(path, "must be a finite 4x4 (or 3x4) matrix", field=key, value=f"shape {matrix.shape}")
        return np.concatenate([matrix, [[0, 0, 0, 1]]]) if matrix.shape == (3, 4) else matrix.astype(np.float64)

    def write_listing(self, root: Path, split: str, header: dict, frames: list) -> Path:
        """`cameras_sphere.npz` for `frames` in the name order of their images (scale_mat: identity)."""
        frames = sorted(frames, key=lambda f: Path(str(f["file_path"])).name)
        arrays = {}
        for i, frame in enumerate(frames):
            fx, fy, cx, cy, skew = frame["K"]
            intrinsics = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            arrays[f"world_mat_{i}"] = projection_from(
                intrinsics, np.asarray(frame["transform_matrix"], dtype=np.float64)
            )
            arrays[f"scale_mat_{i}"] = np.eye(4)
        return atomic_write_numpy(self.listing(root, split), np.savez, **arrays)

    def load(self, root, split="train", background=(1.0, 1.0, 1.0), downscale=1, lazy=False) -> Views:
        root = Path(root)
        path = self.listing(root, split)
        _, frames = self.read_listing(root, split)
        masks = image_files(root, MASKS)
        if masks and len(masks) != len(frames):
            raise DatasetError(
                path,
                f"{root / MASKS} holds {len(masks)} masks for {len(frames)} images",
                field="mask",
                value=len(masks),
            )

        def intrinsics_of(width: int, height: int, i: int):
            fx, fy, cx, cy, _ = frames[i]["K"]  # a skew this small (DTU: < 1e-2 px) is dropped
            return None, (fx, fy, cx, cy)

        return load_frames(
            root,
            path,
            frames,
            background,
            downscale,
            lazy,
            intrinsics_of,
            masks or None,
            camera_field=lambda i: f"world_mat_{i}",
            pose_field=lambda i: f"world_mat_{i}",
        )

    def has_masks(self, root: Path) -> bool:
        return bool(image_files(Path(root), MASKS))

    def fits(self, cameras: Cameras) -> bool:
        return True

    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        return {}, [
            {"K": [float(cameras.fx[i]), float(cameras.fy[i]), float(cameras.cx[i]), float(cameras.cy[i]), 0.0]}
            for i in range(len(cameras))
        ]

    def stored_names(self, views: Views) -> list[tuple[str, str]]:
        # IDR pairs images and masks by order: numbered names keep that order.
        return [(f"{i:06d}", f"{i:03d}.png") for i in range(len(views))]
