"""What the viewer shows of a capture session, read from its run folder and never written there:
the training cameras and their images, the candidate views and the last proposal's scores, each
proposal with the images found beside it, the held-out views of the source dataset, the hemisphere
and the NeRF's box, and the session's last evaluation (`Snapshot`, from `read_snapshot`).

Every file is read as it stands: the session writes its files atomically (`nerfaug.jsonio`), so a
read sees the file before or after a save, never half of it; a file that vanishes or fails to parse
between two looks is read again at the next one (`changed` tells when to look).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from nerfaug import runfiles
from nerfaug.capture.evaluate import EVAL_KIND
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.runfolder import CHECKPOINT_FILE, PROPOSALS_DIR, SESSION_FILE
from nerfaug.capture.state import SessionState
from nerfaug.data.formats import find_split
from nerfaug.data.world_frame import Hemisphere
from nerfaug.errors import PathRefused

THUMBNAIL = 96  # pixels across a training frustum's image: enough to recognise it, light to send
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
EVALUATIONS_LOOKED_AT = 200  # JSON files looked into for the last evaluation, per folder


@dataclass(frozen=True)
class Frustum:
    """A camera to draw: `pose` (4, 4) world-frame OpenGL camera-to-world, vertical field of view
    `fov_y` (radians), `aspect` (width / height), and its image file, if any."""

    name: str
    pose: np.ndarray
    fov_y: float
    aspect: float
    image: Path | None = None


@dataclass(frozen=True)
class ProposalView:
    """One proposal of the session: its record's numbers, its poses (n, 4, 4) world frame, the
    hemisphere map drawn with it and the images found beside it, by view name (renders and
    uncertainty images that `nerfaug uncertainty` or a simulator wrote into the proposals folder)."""

    number: int
    method: str
    step: int
    names: list[str]
    poses: np.ndarray
    map: Path | None
    images: dict[str, list[Path]] = field(default_factory=dict)
    refused: str = ""
    """why its file's folder was not read (a link out of the run folder), or empty."""


@dataclass(frozen=True)
class Candidates:
    """Candidate views: `positions` (C, 3) world frame, `scores` (C,) or None when none were scored,
    the colour bar's `label` (what the score is), and the `chosen` indices (ranked)."""

    positions: np.ndarray
    scores: np.ndarray | None
    label: str
    chosen: list[int]


@dataclass(frozen=True)
class Snapshot:
    """Everything the viewer draws of a session at one moment (see the module docstring)."""

    run_dir: Path
    step: int
    views: int
    engine: str
    hemisphere: Hemisphere
    box_half_size: float
    """half the NeRF box's side, engine units (the box is [-h, h]^3 in the engine frame)."""
    background: tuple[float, float, float]
    training: list[Frustum]
    held_out: list[Frustum]
    candidates: Candidates
    proposals: list[ProposalView]
    evaluation: dict | None


def changed_key(run_dir: Path) -> tuple:
    """What changes when the session trains, proposes or adds: the modification times (ns) of
    session.json, the checkpoint, the proposals folder and each file in it. Cheap to poll."""
    # lstat: a link's own time, never that of what it points to (nothing outside the run is read).
    paths = [runfiles.shown(run_dir, name) for name in (SESSION_FILE, CHECKPOINT_FILE, PROPOSALS_DIR)]
    try:
        folder = runfiles.path_in(run_dir, PROPOSALS_DIR)
        paths += sorted(folder.iterdir()) if folder.is_dir() else []
    except PathRefused:
        pass  # a proposals folder linked out of the run: never listed
    key = []
    for path in paths:
        try:
            key.append((path.name, path.lstat().st_mtime_ns))
        except OSError:
            key.append((path.name, None))
    return tuple(key)


def fov_y(state: SessionState) -> tuple[float, float]:
    """The session camera's vertical field of view (radians) and aspect (width / height)."""
    k = state.intrinsics
    return 2 * math.atan(k.height / (2 * k.fy)), k.width / k.height


def read_snapshot(run_dir: Path) -> Snapshot:
    """The session in `run_dir` as the viewer draws it.

    Raises:
        SessionError: `run_dir` is not a capture session, or its session.json is damaged.
    """
    run_dir = Path(run_dir)
    state = SessionState.read(run_dir)
    folder = SessionFolder(run_dir, state)
    fov, aspect = fov_y(state)
    dataset = folder.dataset_split()
    frames = dataset.frames()
    cameras = folder.cameras
    files = dataset.frame_files(frames)
    training = [
        Frustum(Path(str(f.get("file_path", i))).stem, cameras.camera_to_world[i].double().numpy(), fov, aspect, p)
        for i, (f, p) in enumerate(zip(frames, files))
    ]
    proposals = [_proposal(run_dir, record) for record in state.proposals]
    scene = state.engine_config.get("scene", {})
    box = float(scene.get("box_half_size", state.engine_config.get("box_half_size", 1.5)))
    return Snapshot(
        run_dir=run_dir,
        step=state.step,
        views=len(frames),
        engine=str(state.named_engine() or state.engine),
        hemisphere=state.hemisphere,
        box_half_size=box,
        background=tuple(state.background),
        training=training,
        held_out=_held_out(state, fov, aspect),
        candidates=_candidates(run_dir, state),
        proposals=proposals,
        evaluation=last_evaluation(run_dir),
    )


def _proposal(run_dir: Path, record) -> ProposalView:
    poses = np.asarray(record.poses, dtype=np.float64).reshape(-1, 4, 4)
    try:
        path = runfiles.path_in(run_dir, record.file)
    except PathRefused as error:  # its poses are in session.json; nothing beside a link is read
        return ProposalView(record.number, record.method, record.step, list(record.names), poses, None, {}, str(error))
    picture = path.with_suffix(".png")
    images = {}
    folder = path.parent
    for name in record.names:  # `nerfaug uncertainty --out RUN/proposals/...` or a simulator's captures
        found = [p for p in _images_in(folder) if p.stem == name or p.stem.startswith(f"{name}_")]
        found += [p for p in _images_in(folder / path.stem) if p.stem == name or p.stem.startswith(f"{name}_")]
        if found:
            images[name] = sorted(found)
    return ProposalView(
        number=record.number,
        method=record.method,
        step=record.step,
        names=list(record.names),
        poses=poses,
        map=picture if picture.is_file() else None,
        images=images,
    )


def _images_in(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]


def _candidates(run_dir: Path, state: SessionState) -> Candidates:
    """The last proposal's scored candidates; before any, a sparse start's pool, unscored."""
    if state.proposals:
        record = state.proposals[-1]
        try:
            data = json.loads(runfiles.read_text(run_dir, record.file))
            scored = data["nerfaug"]["candidates"]
            poses = np.asarray(scored["transform_matrix"], dtype=np.float64).reshape(-1, 4, 4)
            scores = np.asarray(scored["scores"], dtype=np.float64)
            label = f"{record.method} score (proposal {record.number}, step {record.step})"
            return Candidates(poses[:, :3, 3], scores, label, [int(i) for i in scored["chosen"]])
        except (OSError, ValueError, KeyError, TypeError):
            pass  # a proposal written without its candidates: the pool, if any, below
    if state.pool is not None:
        try:
            frames = json.loads(runfiles.read_text(run_dir, state.pool))["frames"]
            poses = np.asarray([f["transform_matrix"] for f in frames], dtype=np.float64).reshape(-1, 4, 4)
            return Candidates(poses[:, :3, 3], None, "candidate pool (not scored yet)", [])
        except (OSError, ValueError, KeyError, TypeError):
            pass
    return Candidates(np.zeros((0, 3)), None, "no candidates scored yet", [])


def _held_out(state: SessionState, fov: float, aspect: float) -> list[Frustum]:
    """The source dataset's test split (what `nerfaug eval` scores by default), if it is there."""
    try:
        views = find_split(Path(state.source.data_dir), "test").load(lazy=True)
    except Exception:  # noqa: BLE001 -- a moved or partial source: the viewer draws the rest
        return []
    poses = views.cameras.camera_to_world.double().numpy()
    return [Frustum(name, pose, fov, aspect) for name, pose in zip(views.names, poses)]


def last_evaluation(run_dir: Path) -> dict | None:
    """The newest evaluation of this session (`nerfaug eval --out FILE`) in the run folder or the
    folder beside it: {"file", "step", "split", "mean"}, or None."""
    run = Path(run_dir).resolve()
    found = []
    for folder in (run, run.parent):
        for path in sorted(folder.glob("*.json"))[:EVALUATIONS_LOOKED_AT]:
            try:
                data = json.loads(path.read_text())
                if data.get("nerfaug", {}).get("kind") != EVAL_KIND or Path(data["session"]).resolve() != run:
                    continue
                found.append((path.stat().st_mtime, path, data))
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                continue
    if not found:
        return None
    _, path, data = max(found, key=lambda item: item[0])
    return {"file": str(path), "step": data.get("step"), "split": data.get("split"), "mean": data.get("mean", {})}


def thumbnail(path: Path | None, background, width: int = THUMBNAIL) -> np.ndarray | None:
    """The image at `path` as uint8 (h, w, 3), `width` pixels across, transparency over
    `background`; None when it cannot be read."""
    if path is None:
        return None
    try:
        with Image.open(path) as image:
            image = image.convert("RGBA")
            height = max(1, round(image.height * width / image.width))
            image = image.resize((width, height), Image.Resampling.BILINEAR)
            rgba = np.asarray(image, dtype=np.float32) / 255
    except OSError:
        return None
    rgb = rgba[..., :3] * rgba[..., 3:] + np.asarray(background, dtype=np.float32) * (1 - rgba[..., 3:])
    return (rgb * 255).round().astype(np.uint8)
