"""The nerfstudio / instant-ngp format: one `transforms.json` with intrinsics (`fl_x`, `fl_y`,
`cx`, `cy`, `w`, `h`, globally or per frame) and frames with `file_path` and `transform_matrix`
(OpenGL convention, as in the Blender format)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from nerfaug.camera_schema import check_field_of_view, check_pinhole
from nerfaug.cameras import Cameras
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import (
    check_number,
    load_frames,
    require_frames,
    write_image,
)
from nerfaug.data.interface import Format
from nerfaug.data.lens import lens_of, undistort, undistorted_camera
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_json, read_json

# Keys describing the camera (globally or per frame), kept when a listing is copied as nerfstudio.
CAMERA_KEYS = (
    "camera_model",
    "fl_x",
    "fl_y",
    "cx",
    "cy",
    "w",
    "h",
    "k1",
    "k2",
    "k3",
    "k4",
    "p1",
    "p2",
    "camera_angle_x",
)


# The listing's key of each quantity of `nerfaug.camera_schema.check_pinhole`.
LISTED_AS = {"fx": "fl_x", "fy": "fl_y", "cx": "cx", "cy": "cy", "width": "w", "height": "h"}


def load_nerfstudio(root: str | Path, background=(1.0, 1.0, 1.0), downscale: int = 1, lazy: bool = False) -> Views:
    """Load every frame of a nerfstudio `transforms.json`.

    Intrinsics come from the frame if it has them, else the top level. `camera_angle_x` alone
    (instant-ngp) is accepted too.
    """
    root = Path(root)
    json_path = root / "transforms.json"
    meta = read_json(json_path)
    frames = require_frames(meta, json_path)

    def get_of(i: int):
        frame = frames[i] if isinstance(frames[i], dict) else {}
        return lambda key: frame.get(key, meta.get(key))

    def field_of(i: int):
        frame = frames[i] if isinstance(frames[i], dict) else {}
        return lambda key: f"frames[{i}].{key}" if key in frame else key

    lenses = [lens_of(get_of(i), field_of(i), json_path) for i in range(len(frames))]

    def pinhole_of(width: int, height: int, i: int):
        get, field = get_of(i), field_of(i)

        if get("fl_x") is None:
            if get("camera_angle_x") is None:
                raise DatasetError(
                    json_path,
                    "missing intrinsics: need fl_x (and fl_y, cx, cy) or camera_angle_x",
                    field=f"frames[{i}].fl_x",
                )
            angle = check_field_of_view(get("camera_angle_x"), json_path, field("camera_angle_x"))
            # As Cameras.from_fov: frames may mix a field of view with focal lengths.
            focal = 0.5 * width / math.tan(0.5 * angle)
            return None, (focal, focal, width / 2.0, height / 2.0)
        # Intrinsics are given for the stored (w, h); scale them to the actual file resolution.
        w = width if get("w") is None else check_number(get("w"), json_path, field("w"), 0)
        h = height if get("h") is None else check_number(get("h"), json_path, field("h"), 0)
        fx = check_number(get("fl_x"), json_path, field("fl_x"), 0)
        fy = fx if get("fl_y") is None else check_number(get("fl_y"), json_path, field("fl_y"), 0)
        cx = w / 2 if get("cx") is None else check_number(get("cx"), json_path, field("cx"))
        cy = h / 2 if get("cy") is None else check_number(get("cy"), json_path, field("cy"))
        # The camera as listed, then at the file's size (a field of view does not change with it).
        check_pinhole(fx, fy, cx, cy, w, h, json_path, lambda key: field(LISTED_AS[key]))
        sx, sy = width / w, height / h
        return None, (fx * sx, fy * sy, cx * sx, cy * sy)

    def photo_intrinsics(width: int, height: int, i: int) -> tuple[float, float, float, float]:
        angle, intrinsics = pinhole_of(width, height, i)
        if intrinsics is None:
            focal = 0.5 * width / math.tan(0.5 * angle)
            return focal, focal, width / 2.0, height / 2.0
        return intrinsics

    def intrinsics_of(width: int, height: int, i: int):
        """Frame i's camera at the file's size: the listing's, or the pinhole camera its photo is undistorted to."""
        if lenses[i] is None:
            return pinhole_of(width, height, i)
        photo = photo_intrinsics(width, height, i)
        try:
            return None, undistorted_camera(lenses[i], photo, width, height)
        except ValueError as error:
            raise DatasetError(json_path, str(error), field=f"frames[{i}]", value=lenses[i].describe()) from None

    def warp_of(i: int):
        if lenses[i] is None:
            return None

        def warp(image: np.ndarray) -> np.ndarray:
            height, width = image.shape[:2]
            intrinsics = photo_intrinsics(width, height, i)
            return undistort(image, lenses[i], intrinsics, json_path, f"frames[{i}]")[0]

        return warp

    def camera_field(i: int):
        return lambda key: field_of(i)(LISTED_AS[key])

    return load_frames(
        root, json_path, frames, background, downscale, lazy, intrinsics_of, warp_of=warp_of, camera_field=camera_field
    )


def write_nerfstudio(root: str | Path, views: Views, image_folder: str = "images") -> Path:
    """Write `views` as a nerfstudio `transforms.json` with per-frame intrinsics. Returns its path."""
    root = Path(root)
    views = views.materialised()
    cams = views.cameras
    frames = []
    for i, name in enumerate(views.names):
        stem = Path(name).stem or f"frame_{i:05d}"
        rel = f"{image_folder}/{stem}.png"
        write_image(root / rel, views.images[i], None if views.alphas is None else views.alphas[i])
        frames.append(
            {
                "file_path": rel,
                "transform_matrix": cams.camera_to_world[i].tolist(),
                "fl_x": float(cams.fx[i]),
                "fl_y": float(cams.fy[i]),
                "cx": float(cams.cx[i]),
                "cy": float(cams.cy[i]),
                "w": cams.width,
                "h": cams.height,
            }
        )
    path = root / "transforms.json"
    atomic_write_json(path, {"camera_model": "OPENCV", "w": cams.width, "h": cams.height, "frames": frames})
    return path


def _intrinsics(cameras: Cameras) -> dict:
    return {"fl_x": cameras.fx, "fl_y": cameras.fy, "cx": cameras.cx, "cy": cameras.cy}


class NerfstudioFormat(Format):
    """nerfstudio / instant-ngp: one `transforms.json` for every split, images in `images/`."""

    name = "nerfstudio"
    z_up = None
    fits_rule = "any pinhole cameras, intrinsics per frame"
    camera_keys = CAMERA_KEYS
    has_splits = False

    def listing(self, root: Path, split: str) -> Path:
        return Path(root) / "transforms.json"  # no splits: every split reads all of its frames

    def image_folder(self, split: str) -> str:
        return "images"

    def file_path(self, folder: str, stem: str, suffix: str) -> str:
        return f"{folder}/{stem}{suffix}"

    def load(self, root, split="train", background=(1.0, 1.0, 1.0), downscale=1, lazy=False) -> Views:
        return load_nerfstudio(root, background=background, downscale=downscale, lazy=lazy)

    def fits(self, cameras: Cameras) -> bool:
        return True

    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        """OPENCV pinhole: the intrinsics once at the top level when every camera shares them, else per frame."""
        intrinsics = _intrinsics(cameras)
        header = {"camera_model": "OPENCV", "w": cameras.width, "h": cameras.height}
        shared = all(bool((v - v[0]).abs().max() <= 1e-6 * max(1.0, float(v[0].abs()))) for v in intrinsics.values())
        if shared:
            return header | {k: float(v[0]) for k, v in intrinsics.items()}, [{} for _ in range(len(cameras))]
        return header, [{k: float(v[i]) for k, v in intrinsics.items()} for i in range(len(cameras))]

    def frame_keys(self, camera: Cameras) -> dict:
        keys = {k: float(v[0]) for k, v in _intrinsics(camera).items()}
        return keys | {"w": camera.width, "h": camera.height}

    def lens_distortion(self, header: dict, frames: list) -> bool:
        def distorted(frame: dict) -> bool:
            try:
                return lens_of(lambda key: frame.get(key, header.get(key)), str, Path("transforms.json")) is not None
            except DatasetError:
                return True  # unreadable: kept in this format, whose reader names what is wrong

        return any(distorted(f if isinstance(f, dict) else {}) for f in frames or [{}])

    def appended_keys(self, header: dict, camera: Cameras) -> dict:
        """A new frame's keys; under a header with a lens, the frame says it is a pinhole image (its
        images are taken with the pinhole camera proposals give, not the lens the header describes)."""
        keys = self.frame_keys(camera)
        return keys | {"camera_model": "PINHOLE"} if self.lens_distortion(header, [{}]) else keys

    def write(self, root, split, views, background=(1.0, 1.0, 1.0)) -> Path:
        return write_nerfstudio(root, views)
