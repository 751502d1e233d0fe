"""Adding captured views to a session's dataset: every check first (poses, images, names) into an
`Addition`, then the images and the listing are written through the dataset's format (what
`CaptureSession.add_views` does before training sees them)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.dataset import NAME
from nerfaug.capture.images import as_array, check_capture, collect_images, stored_bytes
from nerfaug.capture.integrity import sha256_bytes
from nerfaug.capture.proposal import Proposal, read_poses
from nerfaug.capture.state import AdditionRecord, DuplicateViews, SessionState, now
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import check_pose
from nerfaug.data.interface import DatasetSplit, NewFrame, unique_stem
from nerfaug.data.views import Views
from nerfaug.jsonio import remove_temp_files


@dataclass(frozen=True)
class Addition:
    """Captures checked against a dataset and ready to write; nothing is on disk yet.

    Attributes:
        names: the new frames' names (image file stems).
        frames: the images as the bytes to store, with their world-frame poses.
        warnings: what was warned about (`DuplicateViews`), one line each.
    """

    names: list[str]
    frames: list[NewFrame]
    warnings: list[str] = field(default_factory=list)


def prepare_addition(
    images,
    poses,
    names: Sequence[str] | None,
    dataset: DatasetSplit,
    camera: Cameras,
    background=(1.0, 1.0, 1.0),
) -> Addition:
    """Check captured images and their poses against `dataset`; see `CaptureSession.add_views`
    for `images`, `poses` and `names`.

    Args:
        dataset: the split the captures join.
        camera: one camera with the dataset's intrinsics (its size is the images' size).
        background: the colour `Views` images were composited over.

    Raises:
        DatasetError: naming the file or index and the value of the first bad input.
    """
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
    captures = collect_images(images, expected_names if is_folder else None, tuple(background))
    if len(captures) != len(checked):
        where = str(images) if isinstance(images, (str, Path)) else "images"
        raise DatasetError(
            where,
            f"got {len(captures)} images but {len(checked)} poses; give one image per pose",
            value=f"{len(captures)} images",
        )
    if expected_names is not None and len(expected_names) != len(checked):
        raise DatasetError(pose_source, f"got {len(expected_names)} names but {len(checked)} poses")
    for capture in captures:
        check_capture(capture, camera.width, camera.height)

    frames = dataset.frames()
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
                dataset.listing,
                f"the dataset already has a frame named {name!r}; was this capture added before?",
                field=f"names[{i}]",
                value=name,
            )
        if name in seen:
            raise DatasetError(pose_source, "two new images share this name", field=f"names[{i}]", value=name)
        seen.add(name)

    repeated = warn_repeated_poses(frames, checked, expected_names, pose_source)
    new_frames = []
    for name, capture, pose in zip(expected_names, captures, checked):
        data, suffix = stored_bytes(capture, png_only=dataset.format.png_only)
        new_frames.append(NewFrame(name, data, suffix, pose.double().tolist()))
    return Addition(list(expected_names), new_frames, repeated)


def write_addition(addition: Addition, dataset: DatasetSplit, camera: Cameras) -> dict[str, str]:
    """Write the images, then the listing (atomically). Returns each new frame's `file_path` ->
    sha256 digest of its image (for the session's integrity record).

    First the temporary files an earlier addition killed mid-write left there (named as
    `nerfaug.jsonio`'s, nothing else) are removed: the caller holds the session's lock, so no
    other writer has one under way."""
    root = Path(dataset.root)
    for folder in (root / dataset.format.image_folder(dataset.split), root):
        remove_temp_files(folder)
    listed = dataset.append(addition.frames, camera)
    return {str(f["file_path"]): sha256_bytes(new.data) for f, new in zip(listed, addition.frames)}


def warn_repeated_poses(frames: list, poses: torch.Tensor, names: Sequence[str], source: str) -> list[str]:
    """Warn (`DuplicateViews`) for each new pose equal to a pose already in the dataset or to
    another new one: the same view added twice trains on one viewpoint as if it were two.
    Returns the warnings' lines (for a caller that reports them elsewhere, as the service does).

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
    lines = []
    for i, j in close.nonzero().tolist():
        if j < len(old) or j - len(old) > i:
            lines.append(f"{source}: new view {names[i]} has the same pose as {labels[j]} (the same view added twice)")
            warnings.warn(lines[-1], DuplicateViews, stacklevel=4)
    return lines


def unrecorded_addition(state: SessionState, frames: list, step: int) -> AdditionRecord | None:
    """The record of views the dataset lists beyond the model's last save that no addition
    records (an `add` stopped after writing its listing and before saving), or None: each view a
    session trains on is one of its records, so they are recorded as found, at `step`."""
    recorded = {name for record in state.additions for name in record.names}
    names = [stem for f in frames if (stem := Path(str(f["file_path"])).stem) not in recorded]
    if not names:
        return None
    matched = [p.number for p in state.proposals if set(names) <= set(p.names)]
    found = "recorded when the session was next opened: the command that added them stopped before saving"
    return AdditionRecord(
        step=step, names=names, proposal=matched[-1] if matched else None, created=now(), warnings=[found]
    )
