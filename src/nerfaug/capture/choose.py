"""How a session chooses its next views: what is asked (`ProposalRequest`, checked here for the
library, the CLI and the service), the candidate cameras, the selection method's call on the
session's NeRF (`SessionModel`), and the proposal's record."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.constraints import ViewConstraints, constrained_indices
from nerfaug.capture.images import as_array
from nerfaug.capture.model import SessionModel
from nerfaug.capture.proposal import Proposal, proposal_seed, read_poses
from nerfaug.capture.requests import RequestError, check_seed
from nerfaug.capture.state import ProposalRecord, now
from nerfaug.data.frame import ENGINE_RADIUS
from nerfaug.data.frames import check_pose
from nerfaug.progress import progress_bar
from nerfaug.selection.candidates import with_poses

if TYPE_CHECKING:
    from torch import Tensor

    from nerfaug.selection import SelectionConfig


def check_method(method: str) -> None:
    """Raise RequestError unless `method` names a selection method."""
    from nerfaug.selection import METHODS

    if method not in METHODS:
        raise RequestError(
            "method",
            method,
            f"unknown selection method; choose one of {', '.join(METHODS)} (`nerfaug methods` describes them)",
        )


@dataclass(frozen=True)
class ProposalRequest:
    """What to propose; see `CaptureSession.propose` for each argument.

    `checked()` is the one place its values are checked: the library, the CLI (before it opens the
    session) and the service call it.
    """

    n: int = 6
    method: str = "ours"
    candidates: str | Path | Cameras | Tensor | np.ndarray | None = None
    n_candidates: int = 500
    seed: int | None = None
    config: SelectionConfig | dict | None = None
    map: bool = True
    constraints: ViewConstraints | dict | None = None
    min_separation: float = 0.0

    def checked(self) -> ProposalRequest:
        """This request with `config` a `SelectionConfig` (or None) and `constraints` a checked
        `ViewConstraints` (or None).

        Raises:
            RequestError: naming the first argument out of range and its value.
            ValueError: a constraint or selection setting that is not valid (naming it).
        """
        from nerfaug.selection import SelectionConfig

        check_method(self.method)
        if int(self.n) != self.n or int(self.n) < 1:
            raise RequestError("n", self.n, "must be >= 1 (a whole number of views to propose)")
        if int(self.n_candidates) < 1:
            raise RequestError("n_candidates", self.n_candidates, "must be >= 1")
        seed = None if self.seed is None else check_seed(self.seed)
        if not 0 <= float(self.min_separation) < 180:
            raise RequestError("min_separation", self.min_separation, "must be in [0, 180) degrees")
        config = SelectionConfig.from_dict(self.config) if isinstance(self.config, dict) else self.config
        constraints = self.constraints
        if isinstance(constraints, dict):
            constraints = ViewConstraints.from_dict(constraints)
        elif constraints is not None:
            constraints = constraints.check()
        return replace(
            self,
            n=int(self.n),
            seed=seed,
            config=config,
            constraints=constraints,
            min_separation=float(self.min_separation),
        )


def describe_candidates(candidates) -> str:
    """How session.json names the candidates of a proposal."""
    if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
        return "hemisphere"
    if isinstance(candidates, (str, Path)):
        return str(candidates)
    return "given"


def candidate_cameras(
    model: SessionModel, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> Cameras:
    """World-frame candidate cameras (see `CaptureSession.propose`) minus the poses trained on."""
    from nerfaug.selection import hemisphere_candidates, matching_poses

    template, hemisphere = model.template, model.hemisphere
    engine_train = model.train_cameras.to("cpu")
    if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
        engine = hemisphere_candidates(
            template.resized(engine_train.width, engine_train.height),
            n_candidates,
            generator,
            radius=ENGINE_RADIUS,
            training=engine_train,
        )
        return with_poses(template, hemisphere.to_world(engine.camera_to_world))
    if isinstance(candidates, Cameras):
        given = candidates
    elif isinstance(candidates, (str, Path)):
        given = with_poses(template, read_poses(candidates)[0])
    else:
        poses = np.asarray(as_array(candidates), dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise ValueError(f"candidate poses must have shape (n, 4, 4), got {poses.shape}")
        given = with_poses(
            template, torch.stack([check_pose(p, Path("candidates"), f"candidates[{i}]") for i, p in enumerate(poses)])
        )
    # Compared in the engine frame, so the tolerance does not depend on the data's units.
    known = matching_poses(hemisphere.to_engine(given.camera_to_world), engine_train.camera_to_world)
    return given[torch.nonzero(~known).reshape(-1).tolist()]


def propose(
    request: ProposalRequest,
    model: SessionModel,
    number: int,
    folder: Path,
    generator: torch.Generator | None = None,
    progress: bool = False,
) -> tuple[Proposal, ProposalRecord]:
    """Choose `request.n` views to capture next, and write them (with every candidate's score)
    to `folder/proposal_NNN.json` (and the map beside it).

    Args:
        model: the session's NeRF that scores the candidates.
        number: this proposal's number in the session (0 for the first).
        folder: where the proposal's files go (`run/proposals`).
        generator: random source for the candidates and the selector; None seeds one from the
            request's seed, else from the session seed and the proposal number (`proposal_seed`).
        progress: show how many candidates are scored (a live bar, or lines in a pipe).

    Returns:
        The proposal, and its record for the session's history.
    """
    from nerfaug.selection import get_method, select_views

    request = request.checked()
    n, method, hemisphere = request.n, request.method, model.hemisphere
    used_config = get_method(method).effective_config(request.config)
    used_seed = None
    if generator is None:
        used_seed = proposal_seed(model.seed, number) if request.seed is None else int(request.seed)
        generator = torch.Generator().manual_seed(used_seed)
    world = candidate_cameras(model, request.candidates, request.n_candidates, generator)
    world = world[constrained_indices(world.camera_to_world, hemisphere, request.constraints, n).tolist()]
    if len(world) < n:
        raise ValueError(
            f"{describe_candidates(request.candidates)}: cannot propose {n} views from {len(world)} candidates "
            "(poses the model already trains on are left out); ask for fewer views or give more "
            "candidates"
        )
    engine_train = model.train_cameras
    engine = hemisphere.cameras_to_engine(world)
    if (engine.width, engine.height) != (engine_train.width, engine_train.height):
        engine = engine.resized(engine_train.width, engine_train.height)
    with progress_bar(enabled=progress, transient=True) as bar:
        task = bar.add_task(f"scoring candidates ({method})", total=len(engine))
        selection = select_views(
            method,
            model.model,
            engine_train,
            engine.to(model.device),
            n,
            generator,
            request.config,
            min_separation=math.radians(request.min_separation),
            progress=lambda done: bar.update(task, completed=done),
        )
        bar.update(task, completed=len(engine))
    chosen = selection.indices.long()
    poses = world.camera_to_world[chosen]
    azimuth, polar, _ = hemisphere.angles(poses)
    names = [f"capture_{number:03d}_{i:02d}" for i in range(n)]
    map_path = None
    if request.map:
        from nerfaug.maps import plot_hemisphere_map

        map_path = plot_hemisphere_map(
            engine.camera_to_world,
            selection.scores,
            engine_train.camera_to_world.cpu(),
            engine.camera_to_world[chosen],
            path=folder / f"proposal_{number:03d}.png",
            title=f"proposal {number}: {method} at step {model.step}",
        )
    proposal = Proposal(
        number=number,
        method=selection.method or method,
        poses=poses,
        names=names,
        azimuth=azimuth,
        polar=polar,
        indices=chosen,
        candidates=world,
        scores=selection.scores.float(),
        components=dict(selection.components),
        map_path=map_path,
        step=model.step,
        seed=used_seed,
        camera_angle_x=float(world.camera_angle_x[0]),
        hemisphere=hemisphere,
        min_separation=request.min_separation,
    )
    record_path = proposal.write(folder / f"proposal_{number:03d}.json", include_candidates=True)
    record = ProposalRecord(
        number=number,
        method=proposal.method,
        n=n,
        step=model.step,
        seed=used_seed,
        candidates=describe_candidates(request.candidates),
        n_candidates=len(world),
        names=names,
        poses=poses.tolist(),
        azimuth=azimuth.tolist(),
        polar=polar.tolist(),
        file=f"{folder.name}/{record_path.name}",
        created=now(),
        extra={"selection": used_config.to_dict()}
        | constraints_record(request.constraints)
        | separation_record(request.min_separation),
    )
    return proposal, record


def separation_record(min_separation: float) -> dict:
    """What a proposal's record keeps of its minimum separation (degrees): nothing when off."""
    return {"min_separation": float(min_separation)} if min_separation > 0 else {}


def constraints_record(constraints: ViewConstraints | None) -> dict:
    """What a proposal's record keeps of its constraints: nothing when there were none."""
    return {} if constraints is None or constraints.empty else {"constraints": constraints.to_dict()}
