"""Proposals: the views a session asks to capture next, written as a Blender-style transforms
JSON (world-frame poses, every candidate's score) that a robot, Blender or `add_views` reads."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

import nerfaug
from nerfaug import owned, runfiles
from nerfaug.cameras import Cameras
from nerfaug.capture.runfolder import RUN_KIND, SESSION_FILE
from nerfaug.data import DatasetError
from nerfaug.data.frames import check_pose
from nerfaug.data.world_frame import Hemisphere
from nerfaug.errors import FolderRefused
from nerfaug.jsonio import atomic_write_bytes, atomic_write_json, read_json
from nerfaug.selection.separation import view_directions


def proposal_seed(seed: int, number: int) -> int:
    """The seed of proposal `number` of a session seeded with `seed`: independent of the global
    RNG and of everything done before, so a resumed session proposes what the original would; at
    most `requests.SEED_MAX` (2^53 - 1), so a JSON client reads it back exactly."""
    return int(np.random.SeedSequence([int(seed), int(number)]).generate_state(1, np.uint64)[0] >> np.uint64(11))


@dataclass(kw_only=True)
class Proposal:
    """The views a session proposes to capture next (built by keyword).

    Attributes:
        number: the session's proposal counter (0 for the first).
        method: the selection method (`nerfaug methods`).
        poses: Tensor with shape (n, 4, 4), world-frame OpenGL camera-to-world: where to capture.
        names: n suggested image names (file stems), e.g. "capture_000_00"; `add_views` matches
            captured files to poses by them.
        azimuth, polar: Tensors with shape (n,), radians, about the hemisphere's centre and up
            (`elevation`, pi/2 - polar, is what every output shows).
        indices: Tensor with shape (n,), the chosen candidates' indices.
        candidates: the world-frame cameras that were scored (n_candidates).
        scores: Tensor with shape (n_candidates,), every candidate's score (bright on the map).
        components: name -> Tensor with shape (n_candidates,), the terms behind the scores.
        map_path: the hemisphere map PNG (scores, training views, chosen views), or None.
        step: training step of the model that scored them.
        seed: the seed of the generator used (None when the caller passed a generator).
        camera_angle_x: horizontal field of view of the cameras, radians.
        hemisphere: the session's hemisphere.
        min_separation: the least angle, degrees about the hemisphere's centre, between two of
            its views; 0 when switched off.
        uniform_fill: how many of the views were drawn uniformly because fewer candidates than
            asked for had a positive score (the model gave them no information); 0 when none.
    """

    number: int
    method: str
    poses: Tensor
    names: list[str]
    azimuth: Tensor
    polar: Tensor
    indices: Tensor
    candidates: Cameras
    scores: Tensor
    components: dict[str, Tensor]
    map_path: Path | None
    step: int
    seed: int | None
    camera_angle_x: float
    hemisphere: Hemisphere
    min_separation: float = 0.0
    uniform_fill: int = 0

    def __len__(self) -> int:
        return self.poses.shape[0]

    @property
    def elevation(self) -> Tensor:
        """Tensor with shape (n,): radians above the hemisphere's equator (pi/2 - polar)."""
        return math.pi / 2 - self.polar

    def transforms(self, include_candidates: bool = False) -> dict:
        """A Blender-style transforms dict, ready for a robot or for Blender:
        {camera_angle_x, w, h, fl_x, fl_y, cx, cy, frames: [{file_path, transform_matrix,
        azimuth, elevation, score}], nerfaug: {...}} (angles in radians, elevation above the
        hemisphere's equator). The extra keys are ignored by other readers."""
        c = self.candidates
        chosen = self.indices.tolist()
        frames = [
            {
                "file_path": f"./{name}",
                "transform_matrix": pose.tolist(),
                "azimuth": float(a),
                "elevation": float(e),
                "score": float(self.scores[i]),
            }
            for name, pose, a, e, i in zip(self.names, self.poses.double(), self.azimuth, self.elevation, chosen)
        ]
        info = {
            "proposal": self.number,
            "method": self.method,
            "step": self.step,
            "seed": self.seed,
            "hemisphere": self.hemisphere.to_dict(),
            "nerfaug": nerfaug.__version__,
            "map": None if self.map_path is None else str(self.map_path),
        }
        info["min_separation"] = self.min_separation
        if self.uniform_fill:
            info["uniform_fill"] = self.uniform_fill
        if include_candidates:
            info["candidates"] = {
                "transform_matrix": c.camera_to_world.tolist(),
                "scores": self.scores.tolist(),
                "components": {k: v.tolist() for k, v in self.components.items()},
                "chosen": chosen,
            }
        return {
            "camera_angle_x": self.camera_angle_x,
            "w": c.width,
            "h": c.height,
            "fl_x": float(c.fx[0]),
            "fl_y": float(c.fy[0]),
            "cx": float(c.cx[0]),
            "cy": float(c.cy[0]),
            "frames": frames,
            "nerfaug": info,
        }

    def write(self, path: str | Path, include_candidates: bool = False) -> Path:
        """Write `transforms()` to `path` (JSON) and the map beside it (`path` with suffix .png).

        Returns the JSON path.
        """
        path = Path(path)
        data = self.transforms(include_candidates)
        if self.map_path is not None and Path(self.map_path).exists():
            map_copy = path.with_suffix(".png")
            image = Path(self.map_path).read_bytes()
            if Path(self.map_path).resolve() != map_copy.resolve():
                atomic_write_bytes(map_copy, image)
            data["nerfaug"]["map"] = map_copy.name
            data["nerfaug"]["map_sha256"] = hashlib.sha256(image).hexdigest()
        data["nerfaug"]["frames_sha256"] = frames_digest(data["frames"])
        atomic_write_json(path, data)
        return path


def nearest_training_views(proposal: Proposal, training: Cameras, names: list[str]) -> list[tuple[str, float]]:
    """Each proposed view's nearest training view and the angle to it, degrees about the
    hemisphere's centre: the selection methods keep a proposal's views apart from one another
    (`min_separation`), never from the views trained on, so one may lie beside a training view.

    Args:
        proposal: its poses (n, 4, 4), world frame.
        training: the training cameras, engine frame (the session's trainer's).
        names: one per training camera.

    Returns:
        n (name, degrees) pairs, in the proposal's order.
    """
    proposed = view_directions(proposal.hemisphere.to_engine(proposal.poses))
    trained = view_directions(training.camera_to_world)
    angles = torch.rad2deg(torch.arccos((proposed @ trained.T).clamp(-1.0, 1.0)))  # (n, n_train)
    nearest = angles.min(dim=1)
    return [(names[int(i)], float(a)) for a, i in zip(nearest.values, nearest.indices)]


def frames_digest(frames: list) -> str:
    """A digest of a poses file's frames: a file whose frames no longer match the digest written
    with them was edited (e.g. poses a robot actually reached) and is not nerfaug's to overwrite."""
    return hashlib.sha256(json.dumps(frames, sort_keys=True).encode()).hexdigest()


def written_by_nerfaug(path: str | Path) -> bool:
    """Whether `path` is a poses file `Proposal.write` wrote and nobody edited since."""
    try:
        data = json.loads(Path(path).read_text())
        info = data["nerfaug"]
        return isinstance(info["proposal"], int) and info["frames_sha256"] == frames_digest(data["frames"])
    except (OSError, ValueError, KeyError, TypeError):
        return False


def map_written_by_nerfaug(path: str | Path) -> bool:
    """Whether the map beside the poses file `path` (same name, .png) is the one `Proposal.write`
    wrote with it, unchanged since (its digest is recorded in the poses file)."""
    path = Path(path)
    try:
        recorded = json.loads(path.read_text())["nerfaug"]["map_sha256"]
        found = hashlib.sha256(path.with_suffix(".png").read_bytes()).hexdigest()
    except (OSError, ValueError, KeyError, TypeError):
        return False
    return written_by_nerfaug(path) and found == recorded


def session_folder_of(path: str | Path) -> Path | None:
    """The capture session's run folder `path` lies in (a folder holding session.json or marked as
    a run folder), or None."""
    for folder in Path(path).resolve().parents:
        if runfiles.exists(folder, SESSION_FILE) or owned.marked(folder, RUN_KIND):
            return folder
    return None


def check_poses_out(out: str | Path, force: bool = False) -> None:
    """Refuse to write a proposal (`out` and the map beside it, `out` with .png) over a file
    nerfaug did not write, or that was edited since (unless `force`), and always inside a
    capture session's folder (its proposals/ are the session's own record).

    Raises:
        FolderRefused: naming the file and what to do.
    """
    out = Path(out)
    image = out.with_suffix(".png")
    if out.suffix.lower() == ".png":
        raise FolderRefused(f"{out}: the map is written beside the poses file with .png; give --out a .json file name")
    if out.exists() and not out.is_file():
        raise FolderRefused(f"{out}: not a file; give --out a .json file name")
    session = session_folder_of(out)
    if session is not None:
        raise FolderRefused(
            f"{out}: lies inside the capture session {session}, whose files are its own record; choose an "
            "--out outside it (the session keeps every proposal in its proposals folder)"
        )
    if force:
        return
    if out.is_file() and not written_by_nerfaug(out):
        raise FolderRefused(
            f"{out}: exists and is not a poses file nerfaug wrote (or was edited since), so it is not "
            "overwritten; choose another --out (or --force to overwrite it)"
        )
    if image.exists() and not (out.is_file() and map_written_by_nerfaug(out)):
        raise FolderRefused(
            f"{image}: exists and is not the map nerfaug wrote with {out.name} (or was changed since), and "
            "would be overwritten by the proposal's map; choose another --out (or --force to overwrite it)"
        )


def read_poses(path: str | Path) -> tuple[Tensor, list[str]]:
    """The poses and frame names of a Blender-style transforms JSON (e.g. a written `Proposal`).

    Returns:
        poses: Tensor with shape (n, 4, 4), float32.
        names: n file stems of the frames' `file_path`.

    Raises:
        DatasetError: naming the file, the frame and the value of a missing or malformed entry.
    """
    path = Path(path)
    data = read_json(path)
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(path, "frames must be a non-empty list", field="frames", value=frames)
    poses, names = [], []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict) or "transform_matrix" not in frame:
            raise DatasetError(path, "each frame needs a transform_matrix", field=f"frames[{i}]", value=frame)
        poses.append(check_pose(frame["transform_matrix"], path, f"frames[{i}].transform_matrix"))
        names.append(Path(str(frame.get("file_path", f"frame_{i:03d}"))).stem)
    return torch.stack(poses), names
