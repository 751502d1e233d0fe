"""The NeRF-synthetic (Blender) format: `transforms_{train,val,test}.json` beside RGBA PNGs.

Each JSON holds `camera_angle_x` (horizontal field of view, radians) and `frames`, each with a
`file_path` (relative, usually without extension) and a 4x4 camera-to-world `transform_matrix`
in the OpenGL convention. Transparent pixels are composited over a background colour.
"""

from __future__ import annotations

from pathlib import Path

import torch

from nerfaug.camera_schema import check_field_of_view
from nerfaug.cameras import Cameras
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import load_frames, require, require_frames, write_image
from nerfaug.data.interface import Format
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_json, read_json

SPLITS = ("train", "val", "test")


def load_blender_split(
    root: str | Path,
    split: str = "train",
    background=(1.0, 1.0, 1.0),
    downscale: int = 1,
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
    angle = check_field_of_view(require(meta, "camera_angle_x", json_path), json_path, "camera_angle_x")
    frames = require_frames(meta, json_path)
    return load_frames(
        root,
        json_path,
        frames,
        background,
        downscale,
        lazy,
        lambda w, h, i: (angle, None),
        camera_field=lambda i: "camera_angle_x",
    )


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
    colour they were loaded over), else RGB. The cameras must fit the format (`blender_fits`), as
    it has a single `camera_angle_x`. Returns the JSON path.
    """
    root = Path(root)
    views = views.materialised()
    cameras = views.cameras
    angles = cameras.camera_angle_x
    if not blender_fits(cameras):
        raise ValueError(f"the Blender format needs {BlenderFormat.fits_rule}; use write_nerfstudio")
    folder = image_folder or split
    frames = []
    for i, name in enumerate(views.names):
        stem = Path(name).name or f"r_{i}"
        rel = f"./{folder}/{Path(stem).stem}"
        alpha = None if views.alphas is None else views.alphas[i]
        write_image(
            root / folder / f"{Path(stem).stem}.png",
            views.images[i],
            alpha,
            torch.as_tensor(background, dtype=torch.float32),
        )
        frames.append({"file_path": rel, "transform_matrix": cameras.camera_to_world[i].tolist()})
    path = root / f"transforms_{split}.json"
    atomic_write_json(path, {"camera_angle_x": float(angles[0]), "frames": frames})
    return path


def blender_fits(cameras: Cameras) -> bool:
    """Whether one `camera_angle_x` describes every camera: one focal length, square pixels and
    the principal point at the image centre (up to float32 round-off of the stored values)."""
    fx, fy, cx, cy = cameras.fx.double(), cameras.fy.double(), cameras.cx.double(), cameras.cy.double()
    tolerance = 1e-4 * float(fx.abs().max())
    return bool(
        (fx - fx[0]).abs().max() <= tolerance
        and (fy - fx).abs().max() <= tolerance
        and (cx - cameras.width / 2).abs().max() <= 1e-3 * cameras.width
        and (cy - cameras.height / 2).abs().max() <= 1e-3 * cameras.height
    )


class BlenderFormat(Format):
    """NeRF-synthetic: `transforms_{split}.json` (one `camera_angle_x`) and `{split}/*.png`."""

    name = "blender"
    fits_rule = "one camera_angle_x: square pixels, centred principal point"
    camera_keys = ("camera_angle_x",)
    png_only = True

    def listing(self, root: Path, split: str) -> Path:
        return Path(root) / f"transforms_{split}.json"

    def image_folder(self, split: str) -> str:
        return split

    def file_path(self, folder: str, stem: str, suffix: str) -> str:
        return f"./{folder}/{stem}"  # the format's readers add ".png"

    def load(self, root, split="train", background=(1.0, 1.0, 1.0), downscale=1, lazy=False) -> Views:
        return load_blender_split(root, split, background=background, downscale=downscale, lazy=lazy)

    def fits(self, cameras: Cameras) -> bool:
        return blender_fits(cameras)

    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        return {"camera_angle_x": float(cameras.camera_angle_x[0])}, [{} for _ in range(len(cameras))]

    def write(self, root, split, views, background=(1.0, 1.0, 1.0)) -> Path:
        return write_blender_split(root, split, views, background=background)
