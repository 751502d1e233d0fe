"""The dataset folder a session grows, in its source's standard format: Blender
(`transforms_train.json` + `train/*.png`) or nerfstudio (`transforms.json` + `images/*`).

`copy_frames` is the one way frames leave one folder for another (a session's copy of its
source at creation, `export`, the source's val/test splits): images are copied byte for byte,
except non-PNG images in the Blender format, which become lossless PNGs.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from nerfaug.cameras import Cameras
from nerfaug.capture.images import read_capture, stored_bytes
from nerfaug.data import DatasetError, load_dataset
from nerfaug.data.frames import resolve_image
from nerfaug.jsonio import atomic_write_bytes, read_json

# A new frame's image name (file stem): no separators, no leading dot.
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
# nerfstudio keys describing the camera, kept when a nerfstudio dataset is copied or exported.
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
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def dataset_json(root: Path, split: str = "train") -> tuple[Path, str]:
    """The transforms file of a dataset folder and its format ("blender" or "nerfstudio").

    Raises:
        DatasetError: no transforms file, or one that is a link to a file outside `root` (a
            session copies and later trusts what it reads there; a link could point anywhere).
    """
    for path, fmt in ((root / f"transforms_{split}.json", "blender"), (root / "transforms.json", "nerfstudio")):
        if path.exists():
            if root.resolve() not in path.resolve().parents:
                raise DatasetError(
                    path, "the transforms file links to a file outside the dataset folder", value=str(path.resolve())
                )
            return path, fmt
    load_dataset(root, split)  # raises the dataset layer's own error, naming what is missing
    raise DatasetError(root, "no transforms file")


# A dataset nerfaug rendered (`nerfaug scene render`) records its settings here; its
# `transforms_initial.json` holds the views taken as already captured, its train split the pool.
RENDER_MANIFEST = "scene.json"


def default_split(root: Path) -> tuple[str, str]:
    """The split a new session trains on when none is given, and why (for the user).

    A dataset nerfaug rendered has a candidate pool of hundreds of views as its train split and
    the views taken as already captured as its initial split: the initial split is the default.
    Any other dataset trains on its train split (or its single nerfstudio transforms file).

    Returns:
        (split, reason): e.g. ("initial", "a dataset nerfaug rendered: ...").
    """
    root = Path(root)
    if (root / RENDER_MANIFEST).is_file() and (root / "transforms_initial.json").is_file():
        return "initial", (
            f"the initial views of a dataset nerfaug rendered ({root / RENDER_MANIFEST}); its train split is "
            "the pool of candidate views, use --split train to train on all of them"
        )
    return "train", "the dataset's train split (--split chooses another)"


def duplicate_frames(cameras: Cameras, names: Sequence[str], tolerance: float = 1e-5) -> list[tuple[str, str]]:
    """Pairs of frames (by name) whose camera poses coincide: the same view twice.

    Args:
        cameras: n cameras; their `camera_to_world` (n, 4, 4) are compared.
        names: n frame names.
        tolerance: largest difference between matrix entries still taken as the same pose.
    """
    poses = cameras.camera_to_world.reshape(len(names), -1).double()
    close = (poses[:, None] - poses[None]).abs().amax(-1) <= tolerance
    return [(names[i], names[j]) for i, j in close.triu(1).nonzero().tolist()]


def frame_files(root: Path, json_path: Path, frames: list) -> list[Path]:
    """The image file of each frame (resolved against `root`; the reader's checks apply)."""
    return [
        resolve_image(root, str(frame["file_path"]), json_path, f"frames[{i}].file_path")
        for i, frame in enumerate(frames)
    ]


def unique_stem(stem: str, taken: set[str]) -> str:
    """`stem` made a safe file name and distinct from `taken` (which it is added to)."""
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".") or "frame"
    candidate, k = stem, 1
    while candidate in taken:
        candidate, k = f"{stem}_{k}", k + 1
    taken.add(candidate)
    return candidate


def file_path(fmt: str, folder: str, stem: str, suffix: str) -> str:
    """A frame's `file_path`: Blender omits the extension (PNG), nerfstudio keeps it."""
    return f"./{folder}/{stem}" if fmt == "blender" else f"{folder}/{stem}{suffix}"


def blender_compatible(cameras: Cameras) -> bool:
    """Whether one `camera_angle_x` describes every camera (square pixels, centred principal point)."""
    fx, fy, cx, cy = cameras.fx.double(), cameras.fy.double(), cameras.cx.double(), cameras.cy.double()
    tolerance = 1e-4 * float(fx.abs().max())
    return bool(
        (fx - fx[0]).abs().max() <= tolerance
        and (fy - fx).abs().max() <= tolerance
        and (cx - cameras.width / 2).abs().max() <= 1e-3 * cameras.width
        and (cy - cameras.height / 2).abs().max() <= 1e-3 * cameras.height
    )


def has_distortion(meta: dict) -> bool:
    """Whether a nerfstudio transforms dict has a non-zero distortion coefficient (global or per frame)."""
    frames = meta.get("frames") or []
    return any(float(meta.get(k) or 0) != 0 for k in DISTORTION_KEYS) or any(
        float(f.get(k) or 0) != 0 for f in frames if isinstance(f, dict) for k in DISTORTION_KEYS
    )


def copy_frames(
    root: Path, json_path: Path, frames: list, out: Path, folder: str, fmt: str, keep: Sequence[str] = ()
) -> list[dict]:
    """Copy the images of `frames` (entries of the transforms file `json_path`, relative to `root`)
    into `out/folder` under unique stems, and return the new frames (not written).

    Every frame's file is resolved before anything is written. Images are copied byte for byte,
    except non-PNG files in the Blender format (`fmt` "blender"), which become PNG.

    Returns:
        One dict per frame: its new `file_path`, its `transform_matrix`, and the keys of `keep`
        the frame has.
    """
    files = frame_files(root, json_path, frames)
    taken: set[str] = set()
    new_frames = []
    for i, (frame, path) in enumerate(zip(frames, files)):
        stem = unique_stem(Path(str(frame["file_path"])).stem, taken)
        data, suffix = stored_bytes(read_capture(path, f"frames[{i}].file_path"), png_only=fmt == "blender")
        atomic_write_bytes(out / folder / f"{stem}{suffix}", data)
        new_frames.append(
            {
                "file_path": file_path(fmt, folder, stem, suffix),
                "transform_matrix": frame["transform_matrix"],
                **{k: frame[k] for k in keep if k in frame},
            }
        )
    return new_frames


def copy_split(
    source: Path, json_path: Path, out: Path, folder: str, fmt: str, camera_angle_x: float | None = None
) -> dict:
    """Copy a transforms file's frames and images into `out/folder` (`copy_frames`). Returns the
    new transforms dict (not written).

    Args:
        fmt: the format to write, "blender" (needs `camera_angle_x` unless the file has one)
            or "nerfstudio" (keeps the camera and distortion keys, globally and per frame).
    """
    meta = read_json(json_path)
    keep = CAMERA_KEYS if fmt == "nerfstudio" else ()
    new_frames = copy_frames(source, json_path, meta["frames"], out, folder, fmt, keep)
    if fmt == "blender":
        angle = meta.get("camera_angle_x", camera_angle_x) if camera_angle_x is None else camera_angle_x
        return {"camera_angle_x": float(angle), "frames": new_frames}
    return {**{k: meta[k] for k in CAMERA_KEYS if k in meta}, "frames": new_frames}
