"""The nerfstudio / instant-ngp format: one `transforms.json` with intrinsics (`fl_x`, `fl_y`,
`cx`, `cy`, `w`, `h`, globally or per frame) and frames with `file_path` and `transform_matrix`
(OpenGL convention, as in the Blender format)."""

from __future__ import annotations

import math
from pathlib import Path

from nerfaug.data.blender import _load_frames
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import atomic_write_json, read_json, require, write_image
from nerfaug.data.views import Views


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
        raise DatasetError(json_path, "frames must be a non-empty list", field="frames")

    def intrinsics_of(width: int, height: int, i: int):
        frame = frames[i]
        get = lambda key: frame.get(key, meta.get(key))
        if get("fl_x") is None:
            if get("camera_angle_x") is not None:
                return float(get("camera_angle_x")), None
            raise DatasetError(json_path, "missing intrinsics: need fl_x (and fl_y, cx, cy) or camera_angle_x",
                               field=f"frames[{i}].fl_x")
        fx = get("fl_x")
        fy = get("fl_y") if get("fl_y") is not None else fx
        w, h = get("w") or width, get("h") or height
        # Intrinsics are given for the stored (w, h); scale to the actual file resolution.
        sx, sy = width / float(w), height / float(h)
        values = [fx, fy, get("cx") if get("cx") is not None else w / 2, get("cy") if get("cy") is not None else h / 2]
        for key, value in zip(("fl_x", "fl_y", "cx", "cy"), values):
            if not isinstance(value, (int, float)) or not math.isfinite(value) or (key.startswith("fl") and value <= 0):
                raise DatasetError(json_path, "intrinsic must be a finite number (focal > 0)", field=f"frames[{i}].{key}", value=value)
        return None, (values[0] * sx, values[1] * sy, values[2] * sx, values[3] * sy)

    return _load_frames(root, json_path, frames, background, downscale, lazy, intrinsics_of)


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
        frames.append({
            "file_path": rel, "transform_matrix": cams.camera_to_world[i].tolist(),
            "fl_x": float(cams.fx[i]), "fl_y": float(cams.fy[i]), "cx": float(cams.cx[i]), "cy": float(cams.cy[i]),
            "w": cams.width, "h": cams.height,
        })
    path = root / "transforms.json"
    atomic_write_json(path, {"camera_model": "OPENCV", "w": cams.width, "h": cams.height, "frames": frames})
    return path
