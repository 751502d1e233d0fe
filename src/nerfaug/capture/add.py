"""Adding captured views to a session: every check first (poses, images, names), then the images,
then the transforms file, then training sees them (what `CaptureSession.add_views` does)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from nerfaug.capture.dataset import NAME, file_path, unique_stem
from nerfaug.capture.images import as_array, check_capture, collect_images, stored_bytes
from nerfaug.capture.integrity import sha256_bytes
from nerfaug.capture.proposal import Proposal, read_poses
from nerfaug.capture.state import AdditionRecord, DuplicateViews, now
from nerfaug.data import DatasetError, Views
from nerfaug.data.frames import check_pose
from nerfaug.jsonio import atomic_write_bytes, atomic_write_json, read_json


def add_views(session, images, poses=None, names: Sequence[str] | None = None) -> list[str]:
    """`CaptureSession.add_views`: check everything, then write the images and the transforms file."""
    session.require_model()
    expected_names: list[str] | None = None
    pose_source = "poses"
    if poses is None:
        if not isinstance(images, Views):
            raise ValueError("poses are needed unless images are Views with their cameras")
        poses = images.cameras.camera_to_world
    if isinstance(poses, Proposal):
        expected_names, poses = list(poses.names), poses.poses
    elif isinstance(poses, (str, Path)):
        pose_source = str(poses)
        poses, expected_names = read_poses(poses)
    array = np.asarray(as_array(poses), dtype=np.float64)
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3 or array.shape[1:] != (4, 4):
        raise DatasetError(pose_source, "poses must have shape (n, 4, 4)", value=f"shape {array.shape}")
    checked = torch.stack([check_pose(p, Path(pose_source), f"poses[{i}]") for i, p in enumerate(array)])

    if names is not None:
        expected_names = list(names)
    is_folder = isinstance(images, (str, Path)) and Path(images).is_dir()
    captures = collect_images(images, expected_names if is_folder else None, tuple(session.state.background))
    if len(captures) != len(checked):
        where = str(images) if isinstance(images, (str, Path)) else "images"
        raise DatasetError(
            where,
            f"got {len(captures)} images but {len(checked)} poses; give one image per pose",
            value=f"{len(captures)} images",
        )
    if expected_names is not None and len(expected_names) != len(checked):
        raise DatasetError(pose_source, f"got {len(expected_names)} names but {len(checked)} poses")
    k = session.state.intrinsics
    for capture in captures:
        check_capture(capture, k.width, k.height)

    json_path = session.json_path()
    meta = read_json(json_path)
    frames = session.frames()
    existing = {Path(str(f["file_path"])).stem for f in frames}
    if expected_names is None:
        from_files = [c.name for c in captures]
        if all(from_files) and len(set(from_files)) == len(from_files):
            expected_names = from_files
        else:
            taken = set(existing)
            expected_names = [unique_stem(f"view_{len(frames) + i:04d}", taken) for i in range(len(captures))]
    seen: set[str] = set()
    for i, name in enumerate(expected_names):
        if not NAME.fullmatch(name):
            raise DatasetError(
                pose_source,
                "an image name may hold only letters, digits, '.', '_', '-'",
                field=f"names[{i}]",
                value=name,
            )
        if name in existing:
            raise DatasetError(
                json_path,
                f"the dataset already has a frame named {name!r}; was this capture added before?",
                field=f"names[{i}]",
                value=name,
            )
        if name in seen:
            raise DatasetError(pose_source, "two new images share this name", field=f"names[{i}]", value=name)
        seen.add(name)

    warn_repeated_poses(frames, checked, expected_names, pose_source)
    fmt, folder = session.state.dataset.format, session.state.dataset.folder
    new_frames = []
    for name, capture, pose in zip(expected_names, captures, checked):
        data, suffix = stored_bytes(capture, png_only=fmt == "blender")
        atomic_write_bytes(session.dataset_dir / folder / f"{name}{suffix}", data)
        frame = {"file_path": file_path(fmt, folder, name, suffix), "transform_matrix": pose.double().tolist()}
        session.state.integrity.captures[frame["file_path"]] = sha256_bytes(data)
        if fmt == "nerfstudio":
            frame.update({"fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height})
        new_frames.append(frame)
    start = len(frames)
    atomic_write_json(json_path, {**meta, "frames": frames + new_frames})

    session.trainer.add_views(session.engine_views(start))
    session.state.views_in_model = len(session.trainer.train_views)
    matched = [p.number for p in session.state.proposals if set(expected_names) <= set(p.names)]
    session.state.additions.append(
        AdditionRecord(
            step=session.step,
            names=list(expected_names),
            proposal=matched[-1] if matched else None,
            created=now(),
        )
    )
    return list(expected_names)


def warn_repeated_poses(frames: list, poses: torch.Tensor, names: Sequence[str], source: str) -> None:
    """Warn (`DuplicateViews`) for each new pose equal to a pose already in the dataset or to
    another new one: the same view added twice trains on one viewpoint as if it were two.

    Args:
        frames: the dataset's frames (each with a `transform_matrix`).
        poses: Tensor with shape (n, 4, 4), the new world-frame poses.
        names: n names of the new frames.
        source: where the poses came from, for the message.
    """
    old_names = [Path(str(f["file_path"])).stem for f in frames]
    old = torch.tensor([f["transform_matrix"] for f in frames], dtype=torch.float64).reshape(len(frames), 16)
    new = poses.double().reshape(len(names), 16)
    every = torch.cat([old, new])
    labels = [f"{n} (in the dataset)" for n in old_names] + list(names)
    close = (new[:, None] - every[None]).abs().amax(-1) <= 1e-5  # float32 poses read back
    for i, j in close.nonzero().tolist():
        if j < len(old) or j - len(old) > i:
            warnings.warn(
                f"{source}: new view {names[i]} has the same pose as {labels[j]} (the same view added twice)",
                DuplicateViews,
                stacklevel=3,
            )
