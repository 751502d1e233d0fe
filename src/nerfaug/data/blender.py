"""The NeRF-synthetic (Blender) format: `transforms_{train,val,test}.json` beside RGBA PNGs.

Each JSON holds `camera_angle_x` (horizontal field of view, radians) and `frames`, each with a
`file_path` (relative, usually without extension) and a 4x4 camera-to-world `transform_matrix`
in the OpenGL convention. Transparent pixels are composited over a background colour.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from nerfaug.cameras import Cameras
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import (
    atomic_write_json, check_pose, read_image, read_json, require, resolve_image, write_image,
)
from nerfaug.data.views import Views

SPLITS = ("train", "val", "test")


def load_blender_split(
    root: str | Path, split: str = "train", background=(1.0, 1.0, 1.0), downscale: int = 1,
    lazy: bool = False,
) -> Views:
    """Load one split of a Blender-format dataset.

    Args:
        root: folder holding `transforms_{split}.json`.
        background: RGB in [0, 1] composited behind transparent pixels (white, as NeRF-synthetic).
        downscale: integer factor to shrink images (and intrinsics) by.
        lazy: read only the first image now (for its size) and the rest on access.

    Raises:
        DatasetError: naming the file, frame and value for any missing or malformed input.
    """
    root = Path(root)
    json_path = root / f"transforms_{split}.json"
    meta = read_json(json_path)
    angle = require(meta, "camera_angle_x", json_path)
    if not isinstance(angle, (int, float)) or not 0 < float(angle) < 3.14159:
        raise DatasetError(json_path, "camera_angle_x must be a number in (0, pi) radians", field="camera_angle_x", value=angle)
    frames = require(meta, "frames", json_path)
    if not isinstance(frames, list) or not frames:
        raise DatasetError(json_path, "frames must be a non-empty list", field="frames", value=frames if not isinstance(frames, list) else [])
    return _load_frames(root, json_path, frames, background, downscale, lazy, lambda w, h, i: (float(angle), None))


def _load_frames(root, json_path, frames, background, downscale, lazy, intrinsics_of) -> Views:
    """Shared by both formats. `intrinsics_of(w, h, i)` gives (camera_angle_x, None) or
    (None, (fx, fy, cx, cy)) for frame i at the file's resolution."""
    background = torch.as_tensor(background, dtype=torch.float32)
    poses, paths, names = [], [], []
    for i, frame in enumerate(frames):
        field = f"frames[{i}]"
        if not isinstance(frame, dict):
            raise DatasetError(json_path, "each frame must be an object", field=field, value=frame)
        file_path = require(frame, "file_path", json_path, f" in {field}")
        poses.append(check_pose(require(frame, "transform_matrix", json_path, f" in {field}"), json_path, f"{field}.transform_matrix"))
        paths.append(resolve_image(root, str(file_path), json_path, f"{field}.file_path"))
        names.append(str(file_path))

    def load(i: int):
        return read_image(paths[i], background, downscale, json_path, f"frames[{i}].file_path")

    first, first_alpha = load(0)
    height, width = first.shape[:2]
    loaded = [(first, first_alpha)] + ([] if lazy else [load(i) for i in range(1, len(frames))])
    for i, (image, _) in enumerate(loaded):
        if image.shape[:2] != (height, width):
            raise DatasetError(
                json_path, f"image size differs from frames[0]'s {width}x{height}",
                field=f"frames[{i}].file_path", value=f"{image.shape[1]}x{image.shape[0]} ({paths[i]})",
            )
    full_w, full_h = width * downscale, height * downscale
    c2w = torch.stack(poses)
    per_frame = [intrinsics_of(full_w, full_h, i) for i in range(len(frames))]
    if per_frame[0][0] is not None:
        cameras = Cameras.from_fov(c2w, per_frame[0][0], full_w, full_h)
    else:
        fx, fy, cx, cy = (torch.tensor([p[1][k] for p in per_frame]) for k in range(4))
        cameras = Cameras(c2w, fx, fy, cx, cy, full_w, full_h)
    cameras = cameras.resized(width, height) if downscale > 1 else cameras

    if lazy:
        def checked_load(i: int):
            image, alpha = load(i)
            if image.shape[:2] != (height, width):
                raise DatasetError(json_path, f"image size differs from frames[0]'s {width}x{height}",
                                   field=f"frames[{i}].file_path", value=f"{image.shape[1]}x{image.shape[0]}")
            return image, alpha
        return Views(cameras, None, names, None, loader=checked_load)
    images = torch.stack([im for im, _ in loaded])
    alphas = torch.stack([a for _, a in loaded]) if all(a is not None for _, a in loaded) else None
    return Views(cameras, images, names, alphas)


def load_blender(root: str | Path, splits=SPLITS, **kwargs) -> dict[str, Views]:
    """Every split of `splits` that exists under `root` (at least one must)."""
    root = Path(root)
    found = {s: load_blender_split(root, s, **kwargs) for s in splits if (root / f"transforms_{s}.json").exists()}
    if not found:
        raise DatasetError(root, f"no transforms_{{{','.join(splits)}}}.json in this folder")
    return found


def write_blender_split(
    root: str | Path, split: str, views: Views, image_folder: str | None = None, background=(1.0, 1.0, 1.0)
) -> Path:
    """Write `views` as a Blender-format split (PNG images + `transforms_{split}.json`).

    Images are written with their alpha when known (RGBA, un-composited from `background`, the
    colour they were loaded over), else RGB. Cameras must share one
    horizontal field of view with square pixels, as the format has a single `camera_angle_x`.
    Returns the JSON path.
    """
    root = Path(root)
    views = views.materialised()
    cameras = views.cameras
    angles = cameras.camera_angle_x
    if (angles - angles[0]).abs().max() > 1e-5 or (cameras.fx - cameras.fy).abs().max() > 1e-3 * cameras.fx.abs().max():
        raise ValueError("the Blender format needs one camera_angle_x and square pixels; use write_nerfstudio")
    folder = image_folder or split
    frames = []
    for i, name in enumerate(views.names):
        stem = Path(name).name or f"r_{i}"
        rel = f"./{folder}/{Path(stem).stem}"
        alpha = None if views.alphas is None else views.alphas[i]
        write_image(root / folder / f"{Path(stem).stem}.png", views.images[i], alpha,
                    torch.as_tensor(background, dtype=torch.float32))
        frames.append({"file_path": rel, "transform_matrix": cameras.camera_to_world[i].tolist()})
    path = root / f"transforms_{split}.json"
    atomic_write_json(path, {"camera_angle_x": float(angles[0]), "frames": frames})
    return path
