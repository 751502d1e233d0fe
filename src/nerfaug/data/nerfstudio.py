"""The nerfstudio / instant-ngp format: one `transforms.json` with intrinsics (`fl_x`, `fl_y`,
`cx`, `cy`, `w`, `h`, globally or per frame) and frames with `file_path` and `transform_matrix`
(OpenGL convention, as in the Blender format)."""

from __future__ import annotations

import math
from pathlib import Path

from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import (
    MIN_ANGLE,
    check_number,
    load_frames,
    require,
    write_image,
)
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_json, read_json


def load_nerfstudio(root: str | Path, background=(1.0, 1.0, 1.0), downscale: int = 1, lazy: bool = False) -> Views:
    """Load every frame of a nerfstudio `transforms.json`.

    Intrinsics come from the frame if it has them, else the top level. `camera_angle_x` alone
    (instant-ngp) is accepted too.
    """
    root = Path(root)
    json_path = root / "transforms.json"
    meta = read_json(json_path)
    frames = require(meta, "frames", json_path)
    if not isinstance(frames, list) or not frames:
        raise DatasetError(
            json_path,
            "frames must be a non-empty list",
            field="frames",
            value=frames if not isinstance(frames, list) else [],
        )

    def intrinsics_of(width: int, height: int, i: int):
        frame = frames[i]

        def get(key):
            return frame.get(key, meta.get(key))

        def field(key):
            return f"frames[{i}].{key}" if key in frame else key

        if get("fl_x") is None:
            if get("camera_angle_x") is None:
                raise DatasetError(
                    json_path,
                    "missing intrinsics: need fl_x (and fl_y, cx, cy) or camera_angle_x",
                    field=f"frames[{i}].fl_x",
                )
            angle = check_number(get("camera_angle_x"), json_path, field("camera_angle_x"), MIN_ANGLE, math.pi)
            # As Cameras.from_fov: frames may mix a field of view with focal lengths.
            focal = 0.5 * width / math.tan(0.5 * angle)
            return None, (focal, focal, width / 2.0, height / 2.0)
        # Intrinsics are given for the stored (w, h); scale them to the actual file resolution.
        w = width if get("w") is None else check_number(get("w"), json_path, field("w"), 0)
        h = height if get("h") is None else check_number(get("h"), json_path, field("h"), 0)
        for key, value in (("w", w), ("h", h)):
            if value < 1:
                raise DatasetError(json_path, "image size must be at least 1 pixel", field=field(key), value=get(key))
        fx = check_number(get("fl_x"), json_path, field("fl_x"), 0)
        fy = fx if get("fl_y") is None else check_number(get("fl_y"), json_path, field("fl_y"), 0)
        cx = w / 2 if get("cx") is None else check_number(get("cx"), json_path, field("cx"))
        cy = h / 2 if get("cy") is None else check_number(get("cy"), json_path, field("cy"))
        sx, sy = width / w, height / h
        scaled = (fx * sx, fy * sy, cx * sx, cy * sy)
        for key, value in zip(("fl_x", "fl_y", "cx", "cy"), scaled):
            # float32 must hold it: a focal of 1e-300 pixels would become 0, one of 1e300 inf.
            if not (1e-6 < value < 1e30 if key.startswith("fl") else abs(value) < 1e30):
                raise DatasetError(
                    json_path,
                    f"intrinsic out of range once scaled to the image's {width}x{height} (w, h = {w:g}, {h:g})",
                    field=field(key),
                    value=get(key),
                )
        return None, scaled

    return load_frames(root, json_path, frames, background, downscale, lazy, intrinsics_of)


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
