"""Writing a session's grown dataset for other tools: nerfstudio (`transforms.json` + `images/`)
or Blender (`transforms_train.json` + `train/`), only into a new, empty or earlier export folder
(what `CaptureSession.export` does)."""

from __future__ import annotations

from pathlib import Path

from nerfaug import owned
from nerfaug.capture.dataset import DISTORTION_KEYS, blender_compatible, copy_frames, copy_split, frame_files
from nerfaug.capture.state import EXPORT_KIND
from nerfaug.errors import FolderRefused
from nerfaug.jsonio import atomic_write_json, read_json


def export(session, out: str | Path, format: str = "nerfstudio", source_splits: bool = True) -> Path:
    """`CaptureSession.export`: the grown dataset in `format`; returns the transforms file."""
    if format not in ("nerfstudio", "blender"):
        raise ValueError(f"format must be 'nerfstudio' or 'blender', got {format!r}")
    out = Path(out)
    if owned.overlaps(out, session.run_dir) or owned.overlaps(out, session.state.source.data_dir):
        raise FolderRefused(
            f"{out}: the export folder must lie outside the run folder {session.run_dir} and "
            f"the source dataset {session.state.source.data_dir}; choose another --out"
        )
    if not owned.is_empty(out) and not owned.marked(out, EXPORT_KIND):
        raise FolderRefused(
            f"{out}: not empty and not an earlier nerfaug export, so nothing is written "
            "there; choose a new or empty folder for --out"
        )
    json_path = session.json_path()
    meta = read_json(json_path)
    frames = session.frames()
    frame_files(session.dataset_dir, json_path, frames)  # every image found before anything is written
    cameras = session.cameras
    if format == "blender" and not blender_compatible(cameras):
        raise ValueError(
            "these cameras do not fit the Blender format (one camera_angle_x, square pixels, "
            "centred principal point); export with format='nerfstudio'"
        )
    folder = "images" if format == "nerfstudio" else "train"
    owned.mark(out, EXPORT_KIND)
    new_frames = copy_frames(session.dataset_dir, json_path, frames, out, folder, format)
    if format == "blender":
        path = out / "transforms_train.json"
        atomic_write_json(path, {"camera_angle_x": float(cameras.camera_angle_x[0]), "frames": new_frames})
        source = Path(session.state.source.data_dir)
        # The source is the user's dataset folder (recorded at creation); its files are read only.
        if source_splits and session.state.source.format == "blender" and source.is_absolute() and source.is_dir():
            for split in ("val", "test"):
                split_json = source / f"transforms_{split}.json"
                if split_json.exists() and split != session.state.source.split:
                    copied = copy_split(source, split_json, out, split, "blender")
                    atomic_write_json(out / split_json.name, copied)
        return path
    intrinsics = {"fl_x": cameras.fx, "fl_y": cameras.fy, "cx": cameras.cx, "cy": cameras.cy}
    shared = all(bool((v - v[0]).abs().max() <= 1e-6 * max(1.0, float(v[0].abs()))) for v in intrinsics.values())
    top = {"camera_model": "OPENCV", "w": cameras.width, "h": cameras.height}
    if meta.get("camera_model"):
        top["camera_model"] = meta["camera_model"]
    top.update({k: meta[k] for k in DISTORTION_KEYS if k in meta})
    if shared:
        top.update({k: float(v[0]) for k, v in intrinsics.items()})
    else:
        for i, frame in enumerate(new_frames):
            frame.update({k: float(v[i]) for k, v in intrinsics.items()})
    path = out / "transforms.json"
    atomic_write_json(path, {**top, "frames": new_frames})
    return path
