"""How a session chooses its next views: what is asked (`ProposalRequest`, a light schema of
`nerfaug.capture.proposal_request`), the candidate cameras, the selection method's call on the
session's NeRF (`SessionModel`), and the proposal's record."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.constraints import constrained_indices
from nerfaug.capture.model import SessionModel
from nerfaug.capture.proposal import Proposal, proposal_seed, read_poses
from nerfaug.capture.proposal_request import ProposalRequest, ViewConstraints
from nerfaug.capture.state import ProposalRecord, now
from nerfaug.data.frames import check_pose
from nerfaug.data.world_frame import ENGINE_RADIUS
from nerfaug.health import EmptyModel, Health
from nerfaug.maps import plot_hemisphere_map
from nerfaug.progress import progress_bar
from nerfaug.selection import hemisphere_candidates, matching_poses, select_views
from nerfaug.selection.candidates import with_poses


def describe_candidates(candidates, pool: bool = False) -> str:
    """How session.json names the candidates of a proposal: hemisphere, the session's pool, the
    file, or given."""
    if pool:
        return "pool"
    if candidates is None:
        return "hemisphere"
    return str(candidates) if isinstance(candidates, Path) else "given"


def candidate_cameras(
    model: SessionModel, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> Cameras:
    """World-frame candidate cameras minus the poses trained on: `n_candidates` poses uniform on
    the session's hemisphere (None; a sparse start's pool, where the session has one), or a
    `ProposalRequest`'s checked reachable poses (a list of 4x4, or a transforms JSON `Path`), with
    the session's intrinsics."""
    return named_candidates(model, candidates, n_candidates, generator)[0]


def named_candidates(
    model: SessionModel, candidates=None, n_candidates: int = 500, generator: torch.Generator | None = None
) -> tuple[Cameras, list[str] | None]:
    """`candidate_cameras`, and the names of the pool's views (None for other candidates)."""
    template, hemisphere = model.template, model.hemisphere
    engine_train = model.train_cameras.to("cpu")
    names = None
    if candidates is None and model.pool is not None:
        poses, names = read_poses(model.pool)
        given = with_poses(template, poses)
    elif candidates is None:
        engine = hemisphere_candidates(
            template.resized(engine_train.width, engine_train.height),
            n_candidates,
            generator,
            radius=ENGINE_RADIUS,
            training=engine_train,
        )
        return with_poses(template, hemisphere.to_world(engine.camera_to_world)), None
    elif isinstance(candidates, Path):
        given = with_poses(template, read_poses(candidates)[0])
    else:
        poses = np.asarray(candidates, dtype=np.float64)
        given = with_poses(
            template, torch.stack([check_pose(p, Path("candidates"), f"candidates[{i}]") for i, p in enumerate(poses)])
        )
    # Compared in the engine frame, so the tolerance does not depend on the data's units.
    known = matching_poses(hemisphere.to_engine(given.camera_to_world), engine_train.camera_to_world)
    kept = torch.nonzero(~known).reshape(-1).tolist()
    return given[kept], None if names is None else [names[i] for i in kept]


def propose(
    request: ProposalRequest,
    model: SessionModel,
    number: int,
    folder: Path,
    generator: torch.Generator | None = None,
    progress: bool = False,
    map: bool = True,
    health: Callable[[], Health] | None = None,
) -> tuple[Proposal, ProposalRecord]:
    """Choose `request.n` views to capture next, and write them (with every candidate's score)
    to `folder/proposal_NNN.json` (and the map beside it).

    `request` is checked already (`CaptureSession.propose` checks it, once).

    Args:
        model: the session's NeRF that scores the candidates.
        number: this proposal's number in the session (0 for the first).
        folder: where the proposal's files go (`run/proposals`).
        generator: random source for the candidates and the selector; None seeds one from the
            request's seed, else from the session seed and the proposal number (`proposal_seed`).
        progress: show how many candidates are scored (a live bar, or lines in a pipe).
        map: draw the hemisphere map of every candidate's score beside the proposal's JSON.
        health: measures whether the NeRF learned its views (`nerfaug.health`), once the request
            and its candidates are found possible (so a refused request says only why) and before
            any candidate is scored.

    Returns:
        The proposal, and its record for the session's history ("empty_model": true when it was
        made, as asked, from an empty NeRF).

    Raises:
        EmptyModel: `health` finds the NeRF empty and the request does not say `allow_empty`.
    """
    n, method, hemisphere = request.n, request.method, model.hemisphere
    used_seed = None
    if generator is None:
        used_seed = proposal_seed(model.seed, number) if request.seed is None else int(request.seed)
        generator = torch.Generator().manual_seed(used_seed)
    world, pool_names = named_candidates(model, request.candidates, request.n_candidates, generator)
    allowed = constrained_indices(world.camera_to_world, hemisphere, request.constraints, n).tolist()
    world = world[allowed]
    from_pool = pool_names is not None
    if len(world) < n:
        raise ValueError(
            f"{describe_candidates(request.candidates, from_pool)}: cannot propose {n} views from {len(world)} "
            "candidates (poses the model already trains on are left out); ask for fewer views or give more "
            "candidates"
        )
    found = health() if health is not None else None
    empty = found is not None and found.empty
    if empty and not request.allow_empty:
        raise EmptyModel(
            f"{folder.parent}: no views proposed: {found.line()} (or ask with allow_empty, `--allow-empty`, to "
            "propose from it all the same)"
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
            request.selection,
            min_separation=math.radians(request.min_separation),
            progress=lambda done: bar.update(task, completed=done),
        )
        bar.update(task, completed=len(engine))
    chosen = selection.indices.long()
    poses = world.camera_to_world[chosen]
    azimuth, polar, _ = hemisphere.angles(poses)
    if from_pool:  # the pool's own names: `add` takes the chosen images from the dataset by them
        names = [pool_names[allowed[i]] for i in chosen.tolist()]
    else:
        names = [f"capture_{number:03d}_{i:02d}" for i in range(n)]
    map_path = None
    if map:
        map_path = plot_hemisphere_map(
            engine.camera_to_world,
            selection.scores,
            engine_train.camera_to_world.cpu(),
            engine.camera_to_world[chosen],
            path=folder / f"proposal_{number:03d}.png",
            title=f"proposal {number}: {method} at step {model.step}",
            label=selection.score_label(request.selection),
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
        uniform_fill=selection.uniform_fill,
    )
    record_path = proposal.write(folder / f"proposal_{number:03d}.json", include_candidates=True)
    record = ProposalRecord(
        number=number,
        method=proposal.method,
        n=n,
        step=model.step,
        seed=used_seed,
        candidates=describe_candidates(request.candidates, from_pool),
        n_candidates=len(world),
        names=names,
        poses=poses.tolist(),
        azimuth=azimuth.tolist(),
        polar=polar.tolist(),
        file=f"{folder.name}/{record_path.name}",
        created=now(),
        selection=selection.config.to_dict(),
        **constraints_record(request.constraints),
        **separation_record(request.min_separation),
        **({"uniform_fill": selection.uniform_fill} if selection.uniform_fill else {}),
        **({"empty_model": True} if empty else {}),
    )
    return proposal, record


def separation_record(min_separation: float) -> dict:
    """What a proposal's record keeps of its minimum separation (degrees; 0 when switched off)."""
    return {"min_separation": float(min_separation)}


def constraints_record(constraints: ViewConstraints | None) -> dict:
    """What a proposal's record keeps of its constraints: nothing when there were none."""
    return {} if constraints is None or constraints.empty else {"constraints": constraints.to_dict()}
